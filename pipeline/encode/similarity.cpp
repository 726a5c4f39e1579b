#if defined(__GNUC__) && !defined(__clang__)
// The comparison loops are the encoder's hot path: vectorize them even in -O2 builds.
#pragma GCC optimize("tree-loop-vectorize", "vect-cost-model=dynamic")
#endif
#include "pipeline/encode/similarity.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <btfvq/error.h>

namespace btfvq {

Metric metric_from(const ParameterDictionary& d, const std::string& key) {
  const std::string metric = d.string(key);
  if (metric == "ssim") return Metric::SSIM;
  if (metric == "mse") return Metric::MSE;
  throw ConfigError(d.origin() + ": '" + key + "' = '" + metric + "' must be \"ssim\" or \"mse\"");
}

SimilaritySettings SimilaritySettings::from(const ParameterDictionary& d) {
  SimilaritySettings s;
  s.metric = metric_from(d, "similarity.metric");
  s.outlier_fraction = d.number("similarity.outlier_fraction", 0.0, 0.5);
  s.k1 = d.number("similarity.k1", 1e-6, 1.0);
  s.k2 = d.number("similarity.k2", 1e-6, 1.0);
  s.chroma_k2 = d.number("similarity.chroma_k2", 1e-6, 1.0);
  s.window_radius = d.integer("similarity.window_radius", 0, 5);
  s.pruning = d.boolean("similarity.pruning");
  s.proxy_candidates = d.integer("similarity.proxy_candidates", 0, 1 << 20);
  s.candidate_limit = d.integer("similarity.candidate_limit", 0, 1 << 20);
  s.proxy_bands = d.integer("similarity.proxy_bands", 1, 64);
  return s;
}

SimilaritySettings SimilaritySettings::defaults() { return from(ParameterDictionary::embedded_default("pipeline")); }

WindowGeometry::WindowGeometry(int rows, int cols, int radius) : rows_(rows), cols_(cols), radius_(radius) {
  inv_count_.resize(size_t(size()));
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const int nr = std::min(rows - 1, r + radius) - std::max(0, r - radius) + 1;
      const int nc = std::min(cols - 1, c + radius) - std::max(0, c - radius) + 1;
      inv_count_[size_t(r * cols + c)] = 1.0f / float(nr * nc);
    }
}

namespace {

// Truncated 3-tap sum along a run of n values with stride 1 (the common radius-1 case).
inline void box3(const float* v, float* out, int n) {
  if (n == 1) {
    out[0] = v[0];
    return;
  }
  out[0] = v[0] + v[1];
  for (int i = 1; i < n - 1; ++i) out[i] = v[i - 1] + v[i] + v[i + 1];
  out[n - 1] = v[n - 2] + v[n - 1];
}

}  // namespace

void WindowGeometry::box(const float* v, float* out, float* tmp) const {
  // Separable: along beta (columns) into tmp, then along alpha (rows) into out.
  if (radius_ == 1) {
    for (int r = 0; r < rows_; ++r) box3(v + r * cols_, tmp + r * cols_, cols_);
    if (rows_ == 1) {
      std::copy(tmp, tmp + cols_, out);
      return;
    }
    for (int r = 0; r < rows_; ++r) {
      float* o = out + r * cols_;
      const float* t = tmp + r * cols_;
      const float* up = r > 0 ? t - cols_ : nullptr;
      const float* down = r < rows_ - 1 ? t + cols_ : nullptr;
      if (up && down)
        for (int c = 0; c < cols_; ++c) o[c] = up[c] + t[c] + down[c];
      else if (up)
        for (int c = 0; c < cols_; ++c) o[c] = up[c] + t[c];
      else
        for (int c = 0; c < cols_; ++c) o[c] = t[c] + down[c];
    }
    return;
  }
  for (int r = 0; r < rows_; ++r) {
    const float* row = v + r * cols_;
    float* t = tmp + r * cols_;
    for (int c = 0; c < cols_; ++c) {
      float s = 0;
      const int lo = std::max(0, c - radius_), hi = std::min(cols_ - 1, c + radius_);
      for (int k = lo; k <= hi; ++k) s += row[k];
      t[c] = s;
    }
  }
  for (int r = 0; r < rows_; ++r) {
    float* o = out + r * cols_;
    const int lo = std::max(0, r - radius_), hi = std::min(rows_ - 1, r + radius_);
    for (int c = 0; c < cols_; ++c) o[c] = 0;
    for (int k = lo; k <= hi; ++k) {
      const float* t = tmp + k * cols_;
      for (int c = 0; c < cols_; ++c) o[c] += t[c];
    }
  }
}

void WindowGeometry::stats(const float* v, float* mean, float* var) const {
  const size_t n = size_t(size());
  thread_local std::vector<float> buffer;
  if (buffer.size() < 3 * n) buffer.resize(3 * n);
  float* sq = buffer.data();
  float* tmp = sq + n;
  float* box_sq = tmp + n;
  for (size_t i = 0; i < n; ++i) sq[i] = v[i] * v[i];
  box(v, mean, tmp);
  box(sq, box_sq, tmp);
  for (size_t i = 0; i < n; ++i) {
    const float w = inv_count_[i];
    mean[i] *= w;
    var[i] = std::max(0.0f, box_sq[i] * w - mean[i] * mean[i]);
  }
}

SliceStore::SliceStore(int channels, const WindowGeometry* g)
    : channels_(channels), g_(g), stride_(size_t(channels) * size_t(g->size()) * 3) {}

void SliceStore::append(const float* values) {
  const size_t n = size_t(g_->size());
  const size_t base = data_.size();
  data_.resize(base + stride_);
  float* v = data_.data() + base;
  std::copy(values, values + size_t(channels_) * n, v);
  for (int c = 0; c < channels_; ++c) {
    float* cv = v + size_t(c) * n;
    g_->stats(cv, v + size_t(channels_) * n + size_t(c) * n, v + 2 * size_t(channels_) * n + size_t(c) * n);
    double s = 0, ss = 0;
    for (size_t i = 0; i < n; ++i) {
      s += cv[i];
      ss += double(cv[i]) * cv[i];
    }
    sums_.push_back(s);
    sums_.push_back(ss);
  }
}

ChannelView SliceStore::view(uint32_t entry, int channel) const {
  const size_t n = size_t(g_->size());
  const float* base = data_.data() + size_t(entry) * stride_;
  ChannelView cv;
  cv.v = base + size_t(channel) * n;
  cv.mean = base + size_t(channels_) * n + size_t(channel) * n;
  cv.var = base + 2 * size_t(channels_) * n + size_t(channel) * n;
  const size_t k = (size_t(entry) * size_t(channels_) + size_t(channel)) * 2;
  cv.sum = sums_[k];
  cv.sumsq = sums_[k + 1];
  return cv;
}

SsimConstants SsimConstants::make(const SimilaritySettings& s, Dynamic dyn, float luminance_range) {
  SsimConstants k;
  for (int c = 0; c < 3; ++c) {
    const double L = (dyn == Dynamic::HDR && c == 0) ? std::max(double(luminance_range), 1e-12) : 255.0;
    k.c1[c] = float((s.k1 * L) * (s.k1 * L));
    const double k2 = c == 0 ? s.k2 : s.chroma_k2;
    k.c2[c] = float((k2 * L) * (k2 * L));
  }
  return k;
}

void ScoreAccumulator::reset(Metric m, size_t total_values, double outlier_fraction, double bound) {
  metric_ = m;
  bound_ = bound;
  alive_ = true;
  sse_ = 0;
  keep_ = size_t(std::floor(outlier_fraction * double(total_values) + 1e-9)) + 1;
  used_ = 0;
  below_ = 0;
  tau_ = std::numeric_limits<float>::infinity();
}

bool ScoreAccumulator::add_ssim(const float* values, int n) {
  // Count first: a candidate that already has more than r values below the bound is dead, and
  // most candidates of a search die this way.
  int below = 0;
  const double bound = bound_;
  for (int k = 0; k < n; ++k) below += double(values[k]) < bound;
  below_ += size_t(below);
  if (below_ >= keep_) {
    alive_ = false;
    return false;
  }
  // Batched selection: keep only values below tau (>= the (r+1)-th smallest so far); when the
  // buffer reaches 2 (r+1) values, select the r+1 smallest and lower tau to the largest of them.
  if (buffer_.size() < used_ + size_t(n)) buffer_.resize(used_ + size_t(n));
  float* buf = buffer_.data();
  size_t m = used_;
  const float tau = tau_;
  for (int k = 0; k < n; ++k) {
    buf[m] = values[k];
    m += values[k] < tau;
  }
  used_ = m;
  if (used_ >= 2 * keep_) {
    std::nth_element(buf, buf + (keep_ - 1), buf + used_);
    tau_ = buf[keep_ - 1];
    used_ = keep_;
  }
  return true;
}

bool ScoreAccumulator::add_squared_error(double sum) {
  sse_ += sum;
  if (-sse_ < bound_) alive_ = false;
  return alive_;
}

double ScoreAccumulator::score() const {
  if (metric_ == Metric::MSE) return -sse_;
  if (used_ == 0) return 1.0;
  // The (r+1)-th smallest value; with fewer values (total_values overstated) the largest one.
  float* buf = buffer_.data();
  const size_t k = std::min(keep_, used_) - 1;
  std::nth_element(buf, buf + k, buf + used_);
  return double(buf[k]);
}

double score_to_dissimilarity(Metric m, double score, size_t total_values) {
  if (m == Metric::SSIM) return 1.0 - score;
  return -score / double(std::max<size_t>(1, total_values));
}

double dissimilarity_to_score(Metric m, double d, size_t total_values) {
  if (m == Metric::SSIM) return 1.0 - d;
  return -d * double(std::max<size_t>(1, total_values));
}

float* ssim_values(const WindowGeometry& g, const ChannelView& x, Affine ax, const ChannelView& y, Affine ay, float c1,
                   float c2, float* scratch) {
  const int n = g.size();
  float* prod = scratch;
  float* exy = scratch + n;
  float* tmp = scratch + 2 * n;
  for (int i = 0; i < n; ++i) prod[i] = x.v[i] * y.v[i];
  g.box(prod, exy, tmp);
  const float bxy = ax.b * ay.b, bxx = ax.b * ax.b, byy = ay.b * ay.b;
  float* ssim = prod;  // reused: products are no longer needed
  for (int i = 0; i < n; ++i) {
    const float mx = ax.a + ax.b * x.mean[i];
    const float my = ay.a + ay.b * y.mean[i];
    const float cov = bxy * (exy[i] * g.inv_count(i) - x.mean[i] * y.mean[i]);
    const float vx = bxx * x.var[i], vy = byy * y.var[i];
    ssim[i] = ((2 * mx * my + c1) * (2 * cov + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2));
  }
  return ssim;
}

bool accumulate_channel(const WindowGeometry& g, Metric metric, const ChannelView& x, Affine ax, const ChannelView& y,
                        Affine ay, float c1, float c2, ScoreAccumulator& acc, float* scratch) {
  const int n = g.size();
  if (metric == Metric::MSE) return acc.add_squared_error(squared_error(n, x, ax, y, ay));
  return acc.add_ssim(ssim_values(g, x, ax, y, ay, c1, c2, scratch), n);
}

double squared_error(int n, const ChannelView& x, Affine ax, const ChannelView& y, Affine ay) {
  double s = 0;
  for (int i = 0; i < n; ++i) {
    const float d = (ax.a + ax.b * x.v[i]) - (ay.a + ay.b * y.v[i]);
    s += double(d) * d;
  }
  return s;
}

bool min_ssim_row(const WindowGeometry& g, const ChannelView& x, Affine ax, const ChannelView& y, Affine ay, float c1,
                  float c2, double bound, double* score) {
  const int n = g.cols();
  const float bxy = ax.b * ay.b, bxx = ax.b * ax.b, byy = ay.b * ay.b;
  float lowest = 2.0f;
  for (int i = 0; i < n; ++i) {
    // Window sum of products in box3's order, so that every value equals accumulate_channel's.
    float exy;
    if (n == 1) exy = x.v[0] * y.v[0];
    else if (i == 0) exy = x.v[0] * y.v[0] + x.v[1] * y.v[1];
    else if (i == n - 1) exy = x.v[n - 2] * y.v[n - 2] + x.v[n - 1] * y.v[n - 1];
    else exy = x.v[i - 1] * y.v[i - 1] + x.v[i] * y.v[i] + x.v[i + 1] * y.v[i + 1];
    const float mx = ax.a + ax.b * x.mean[i];
    const float my = ay.a + ay.b * y.mean[i];
    const float cov = bxy * (exy * g.inv_count(i) - x.mean[i] * y.mean[i]);
    const float vx = bxx * x.var[i], vy = byy * y.var[i];
    const float v = ((2 * mx * my + c1) * (2 * cov + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2));
    if (double(v) < bound) return false;
    lowest = std::min(lowest, v);
  }
  *score = lowest;
  return true;
}

double slice_similarity(const SimilaritySettings& s, Dynamic dyn, const WindowGeometry& g, const float* x,
                        const float* y, int planes, int first_channel, int channels, float luminance_range) {
  const SsimConstants k = SsimConstants::make(s, dyn, luminance_range);
  const size_t n = size_t(g.size());
  const size_t total = n * size_t(planes) * size_t(channels);
  std::vector<float> stats(4 * n), scratch(3 * n);
  ScoreAccumulator acc;
  acc.reset(s.metric, total, s.outlier_fraction, -1e300);
  for (int c = 0; c < channels; ++c)
    for (int p = 0; p < planes; ++p) {
      const size_t off = (size_t(c) * size_t(planes) + size_t(p)) * n;
      ChannelView xv, yv;
      xv.v = x + off;
      yv.v = y + off;
      g.stats(xv.v, stats.data(), stats.data() + n);
      g.stats(yv.v, stats.data() + 2 * n, stats.data() + 3 * n);
      xv.mean = stats.data();
      xv.var = stats.data() + n;
      yv.mean = stats.data() + 2 * n;
      yv.var = stats.data() + 3 * n;
      const int ch = first_channel + c;
      accumulate_channel(g, s.metric, xv, {}, yv, {}, k.c1[ch], k.c2[ch], acc, scratch.data());
    }
  const double sc = acc.score();
  return s.metric == Metric::SSIM ? sc : -score_to_dissimilarity(s.metric, sc, total);
}

}  // namespace btfvq
