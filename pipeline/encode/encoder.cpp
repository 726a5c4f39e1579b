#include "pipeline/encode/encoder.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>

#include <btfvq/error.h>
#include "pipeline/util/bounded_heap.h"
#include "pipeline/util/parallel.h"

namespace btfvq {

namespace {

constexpr double kNoBound = -1e300;
constexpr double kNoCap = std::numeric_limits<double>::infinity();  // a child's own threshold applies

Thresholds read_thresholds(const ParameterDictionary& d, const std::string& prefix, double hi) {
  Thresholds t;
  t.p4 = d.number(prefix + ".p4", 0.0, hi);
  t.p3 = d.number(prefix + ".p3", 0.0, hi);
  t.m = d.number(prefix + ".m", 0.0, hi);
  t.p2 = d.number(prefix + ".p2", 0.0, hi);
  t.p1 = d.number(prefix + ".p1", 0.0, hi);
  t.i2 = d.number(prefix + ".i2", 0.0, hi);
  t.i1 = d.number(prefix + ".i1", 0.0, hi);
  t.c = d.number(prefix + ".c", 0.0, 1e6);
  return t;
}

// The per-sample affine map of stored values in units `unit` to absolute coding-space values.
Affine unit_affine(Dynamic dyn, int channel, float unit) {
  if (!channel_scales(dyn, channel)) return {};
  const float o = channel_offset(dyn, channel);
  return {o * (1.0f - unit), unit};
}

// FNV-1a over the bytes of a row (and of its second table's row): the key of ContentIndex.
uint64_t row_hash(const void* a, size_t na, const void* b, size_t nb) {
  uint64_t h = 1469598103934665603ull;
  auto mix = [&h](const void* p, size_t n) {
    const auto* c = static_cast<const uint8_t*>(p);
    for (size_t i = 0; i < n; ++i) h = (h ^ c[i]) * 1099511628211ull;
  };
  mix(a, na);
  if (b) mix(b, nb);
  return h;
}

template <class A, class B>
uint64_t table_row_hash(const Table<A>& ta, size_t r, const Table<B>* tb) {
  return row_hash(ta.row(r), ta.cols() * sizeof(A), tb ? tb->row(r) : nullptr, tb ? tb->cols() * sizeof(B) : 0);
}

// Marks the insertions below an attempt with its cause for the scope's lifetime (the strongest
// cause of the nesting wins: a leaf inserted under an exact re-encode counts as exact).
template <class C>
class CauseScope {
 public:
  CauseScope(C& c, C now) : c_(c), saved_(c) { c_ = std::max(c_, now); }
  ~CauseScope() { c_ = saved_; }
  CauseScope(const CauseScope&) = delete;
  CauseScope& operator=(const CauseScope&) = delete;

 private:
  C& c_;
  C saved_;
};

float dot(const float* a, const float* b, int n) {
  float s0 = 0, s1 = 0, s2 = 0, s3 = 0;
  int i = 0;
  for (; i + 4 <= n; i += 4) {
    s0 += a[i] * b[i];
    s1 += a[i + 1] * b[i + 1];
    s2 += a[i + 2] * b[i + 2];
    s3 += a[i + 3] * b[i + 3];
  }
  for (; i < n; ++i) s0 += a[i] * b[i];
  return (s0 + s1) + (s2 + s3);
}

}  // namespace

Thresholds Thresholds::from(const ParameterDictionary& d, Metric metric) {
  const Thresholds ssim = read_thresholds(d, "thresholds.ssim", 2.0);
  const Thresholds mse = read_thresholds(d, "thresholds.mse", 1e6);
  return metric == Metric::SSIM ? ssim : mse;
}

Thresholds Thresholds::from(const ParameterDictionary& d) {
  return from(d, SimilaritySettings::from(d).metric);
}

Thresholds Thresholds::defaults(Metric metric) {
  return from(ParameterDictionary::embedded_default("pipeline"), metric);
}

Thresholds Thresholds::relaxed(double f) const {
  if (!(f >= 0) || !std::isfinite(f)) throw ConfigError("threshold relax factor must be a finite number >= 0");
  return {p4 * f, p3 * f, m * f, p2 * f, p1 * f, i2 * f, i1 * f, c * f};
}

void EncoderStats::add(const EncoderStats& o) {
  texels += o.texels;
  comparisons += o.comparisons;
  pruned += o.pruned;
  fallbacks += o.fallbacks;
  laesa_skipped += o.laesa_skipped;
  ahead += o.ahead;
  ahead_extended += o.ahead_extended;
  ahead_redone += o.ahead_redone;
  rows_ahead += o.rows_ahead;
  rows_redone += o.rows_redone;
  for (CodebookId id : kAllCodebooks) {
    inserted_miss[id] += o.inserted_miss[id];
    inserted_retry[id] += o.inserted_retry[id];
    inserted_exact[id] += o.inserted_exact[id];
    reused[id] += o.reused[id];
  }
}

float normalized_brightness(Dynamic dyn) { return dyn == Dynamic::LDR ? 100.0f : 1.0f; }

// The factor that brings a new composite entry of mean brightness `bright` to the fixed brightness
// (its children's scales are divided by it, the parent's scale carries it).
float Encoder::normalization(double bright) const {
  return bright > 1e-6 ? float(bright) / normalized_brightness(dyn_) : 1.0f;
}

// ---------------------------------------------------------------------------------------------
// Per-call scratch and queries.

struct Encoder::Ctx {
  SsimConstants k;
  ScoreAccumulator acc;
  std::vector<float> scratch;
  std::vector<PlaneRef> planes;
  std::vector<uint32_t> order;
  std::vector<uint8_t> tried;
  EncoderStats counts;
  // Candidate orders of the parts a composition is about to search (prime_orders), by level (0: M,
  // 1: P3) and the part's first value; each holds the k nearest among the entries below `end`.
  struct Memo {
    size_t end = 0;
    std::vector<SignatureTable::Neighbour> near;
  };
  std::unordered_map<const float*, Memo> memo[2];
  std::vector<Ctx> side;  // of the pool's threads, for searches made beside this one (side_contexts)
};

namespace {
// ctx.side for n threads: ctx's SSIM constants, scratch of its size, no counts.
std::vector<Encoder::Ctx>& side_contexts(Encoder::Ctx& ctx, size_t n) {
  ctx.side.resize(n);
  for (Encoder::Ctx& c : ctx.side) {
    c.k = ctx.k;
    c.scratch.resize(ctx.scratch.size());
  }
  return ctx.side;
}
// Adds the counts of ctx.side into ctx's, once its searches are done.
void collect_side_counts(Encoder::Ctx& ctx) {
  for (Encoder::Ctx& c : ctx.side) {
    ctx.counts.add(c.counts);
    c.counts = {};
  }
}
}  // namespace

// The input slice: `planes` planes with channels [first, first + channels), values in units `unit`
// (absolute = offset + unit (v - offset) for the channels an RGB scale acts on).
struct Encoder::Query {
  int planes = 0, first = 0, channels = 3;
  float unit = 1.0f;
  std::vector<ChannelView> views;  // planes x channels
  std::vector<float> stats;        // owned window statistics, when not borrowed from a parent
  size_t values = 0;
  // SSIM accumulation order of the planes: most contrast first, where a worse candidate shows its
  // low values soonest and is abandoned early (the percentile does not depend on the order).
  std::vector<int> order;
  const ChannelView& at(int p, int c) const { return views[size_t(p * channels + (c - first))]; }
  void order_planes(int n) {
    std::vector<double> contrast(size_t(planes), 0.0);
    for (int p = 0; p < planes; ++p)
      for (int c = 0; c < channels; ++c) {
        const ChannelView& v = views[size_t(p * channels + c)];
        contrast[size_t(p)] += v.sumsq - v.sum * v.sum / n;
      }
    order.resize(size_t(planes));
    for (int p = 0; p < planes; ++p) order[size_t(p)] = p;
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return contrast[size_t(a)] > contrast[size_t(b)]; });
  }
};

namespace {

// A view of one plane channel whose window statistics are already in mean and var.
ChannelView view_of(const WindowGeometry& g, const float* v, const float* mean, const float* var) {
  ChannelView cv;
  cv.v = v;
  cv.mean = mean;
  cv.var = var;
  double s = 0, ss = 0;
  for (int i = 0; i < g.size(); ++i) {
    s += v[i];
    ss += double(v[i]) * v[i];
  }
  cv.sum = s;
  cv.sumsq = ss;
  return cv;
}

ChannelView make_view(const WindowGeometry& g, const float* v, float* mean, float* var) {
  g.stats(v, mean, var);
  return view_of(g, v, mean, var);
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Caches of the code-books (append-only, like the code-books).

Encoder::Encoder(Codebooks& books, Dynamic dyn, const Thresholds& thresholds, const SimilaritySettings& settings)
    : books_(books), dyn_(dyn), thresholds_(thresholds), settings_(settings), grid_(books.grid) {
  grid_.validate();
  if (books.p1.cols() != size_t(grid_.n_beta) || books.p2_index.cols() != size_t(grid_.n_alpha) ||
      books.p3_index.cols() != size_t(grid_.n_theta_v) || books.p4_index.cols() != size_t(grid_.n_phi_v))
    throw InputError("encoder: the code-book tables do not match the code-books' grid");
  g2_ = WindowGeometry(grid_.n_alpha, grid_.n_beta, settings.window_radius);
  g1_ = WindowGeometry(1, grid_.n_beta, settings.window_radius);
  p1_store_ = SliceStore(1, &g1_);
  i1_store_ = SliceStore(2, &g1_);
  p1_index_ = ProxyIndex(grid_.n_beta, 0.02f);
  i1_index_ = ProxyIndex(2 * grid_.n_beta, 2.0f);
  p2_store_ = SliceStore(1, &g2_);
  i2_store_ = SliceStore(2, &g2_);
  p2_lanes_ = RowLanes(grid_.n_alpha);
  i2_lanes_ = RowLanes(2 * grid_.n_alpha);
  bands_ = std::clamp(settings.proxy_bands, 1, grid_.n_alpha);
  m_sig_ = SignatureTable(3 * grid_.n_alpha + m_bands());
  p3_sig_ = SignatureTable((bands_ + 2) * grid_.n_theta_v);
  p4_sig_ = SignatureTable(3 * grid_.n_theta_v * grid_.n_phi_v);
  Database{books_, {}}.validate();
  sync();
}

void Encoder::sync() {
  while (c_indexed_ < books_.c.rows()) index_c(uint32_t(c_indexed_));
  while (p1_store_.size() < books_.p1.rows()) cache_p1(p1_store_.size());
  while (i1_store_.size() < books_.i1.rows()) cache_i1(i1_store_.size());
  while (p2_store_.size() < books_.p2_index.rows()) cache_p2(p2_store_.size());
  while (i2_store_.size() < books_.i2.rows()) cache_i2(i2_store_.size());
  while (m_bright_.size() < books_.m.rows()) cache_m(uint32_t(m_bright_.size()));
  while (p3_bright_.size() < books_.p3_index.rows()) cache_p3(uint32_t(p3_bright_.size()));
  while (p4_bright_.size() < books_.p4_index.rows()) cache_p4(uint32_t(p4_bright_.size()));
}

namespace {
// Leaders whose lists a 1D search scans (ProxyIndex::nearest).
constexpr int kProbes = 8;
// Candidate planes a composite search needs before its candidates are scored on several threads.
constexpr size_t kParallelPlanes = 32;

// body(j, scratch) for the planes j of a composition check, on the pool's threads when there are
// planes enough to share (a P4 composition's 112), each thread with scratch of its own.
template <class Body>
void for_each_plane(int np, size_t threads, std::vector<float>& scratch, Body body) {
  if (threads <= 1 || size_t(np) < kParallelPlanes) {
    for (int j = 0; j < np; ++j) body(j, scratch.data());
    return;
  }
  std::vector<std::vector<float>> own(parallel_slots(size_t(np), {threads, 1}), std::vector<float>(scratch.size()));
  parallel_for(0, size_t(np), [&](size_t first, size_t last, size_t w) {
    for (size_t j = first; j < last; ++j) body(int(j), own[w].data());
  }, ParallelOptions{threads, 1});
}
// Stored rows a repair tries for a failing row of a plane before it stores the row exactly.
constexpr int kReuseCandidates = 16;

// The row as a unit vector: P1 rows are matched after their best scale, so only the shape counts.
void unit_shape(const float* row, int n, float* out) {
  double s = 0;
  for (int i = 0; i < n; ++i) s += double(row[i]) * row[i];
  const float inv = s > 0 ? float(1.0 / std::sqrt(s)) : 0.0f;
  for (int i = 0; i < n; ++i) out[i] = row[i] * inv;
}
}  // namespace

template <class A, class B>
uint32_t Encoder::insert_row(CodebookId id, ContentIndex& index, Table<A>& ta, const A* a, Table<B>* tb, const B* b,
                             bool exact) {
  const uint64_t h = row_hash(a, ta.cols() * sizeof(A), b, tb ? tb->cols() * sizeof(B) : 0);
  if (const auto it = index.ids.find(h); it != index.ids.end())
    for (uint32_t e : it->second)
      if (std::equal(a, a + ta.cols(), ta.row(e)) && (!tb || std::equal(b, b + tb->cols(), tb->row(e)))) {
        ++stats_.reused[id];
        return e;
      }
  const uint32_t e = ta.append(a);
  if (tb) tb->append(b);
  cache(id, e);
  count_insert(id, exact);
  return e;
}

void Encoder::cache(CodebookId id, uint32_t e) {
  switch (id) {
    case CodebookId::P1: return cache_p1(e);
    case CodebookId::C: return index_c(e);
    case CodebookId::I1: return cache_i1(e);
    case CodebookId::I2: return cache_i2(e);
    case CodebookId::P2: return cache_p2(e);
    case CodebookId::M: return cache_m(e);
    case CodebookId::P3: return cache_p3(e);
    case CodebookId::P4: return cache_p4(e);
  }
}

void Encoder::count_insert(CodebookId id, bool exact) {
  const Cause c = exact ? kExact : cause_;
  (c == kExact ? stats_.inserted_exact : c == kRetry ? stats_.inserted_retry : stats_.inserted_miss)[id] += 1;
}

void Encoder::cache_p1(uint32_t e) {
  p1_rows_.ids[table_row_hash<float, float>(books_.p1, e, nullptr)].push_back(e);
  p1_store_.append(books_.p1.row(e));
  float shape[256];
  if (grid_.n_beta > 256) throw InputError("encoder: n_beta above 256 is not supported");
  unit_shape(books_.p1.row(e), grid_.n_beta, shape);
  p1_index_.insert(shape);
}

namespace {
constexpr float kCCell = 4.0f;  // grid cell of the C index, in stored chroma units
// An "exact" chroma value (a repair) still reuses a stored one within this distance (absolute units,
// about a quarter of a just-noticeable chroma step): without it every repaired sample, JPEG noise
// included, became a C entry of its own (a real sample: C 48,144 instead of 752).
constexpr double kExactC = 1.0;
int64_t c_cell(double v) { return int64_t(std::floor(v / kCCell)); }
uint64_t c_key(int64_t i, int64_t j) { return (uint64_t(uint32_t(int32_t(i))) << 32) | uint32_t(int32_t(j)); }
}  // namespace

void Encoder::index_c(uint32_t e) {
  c_rows_.ids[table_row_hash<float, float>(books_.c, e, nullptr)].push_back(e);
  c_grid_[c_key(c_cell(books_.c.at(e, 0)), c_cell(books_.c.at(e, 1)))].push_back(e);
  c_indexed_ = size_t(e) + 1;
}

void Encoder::cache_i1(uint32_t e) {
  i1_rows_.ids[table_row_hash<uint32_t, uint32_t>(books_.i1, e, nullptr)].push_back(e);
  const int nb = grid_.n_beta;
  std::vector<float> v(static_cast<size_t>(2 * nb));
  for (int b = 0; b < nb; ++b) {
    const uint32_t c = books_.i1.at(e, size_t(b));
    v[size_t(b)] = books_.c.at(c, 0);
    v[size_t(nb + b)] = books_.c.at(c, 1);
  }
  i1_store_.append(v.data());
  i1_index_.insert(v.data());
}

void Encoder::cache_p2(uint32_t e) {
  p2_rows_.ids[table_row_hash(books_.p2_index, e, &books_.p2_scale)].push_back(e);
  const int na = grid_.n_alpha, nb = grid_.n_beta;
  std::vector<float> v(static_cast<size_t>(na * nb));
  for (int a = 0; a < na; ++a) {
    const float s = books_.p2_scale.at(e, size_t(a));
    const float* row = books_.p1.row(books_.p2_index.at(e, size_t(a)));
    for (int b = 0; b < nb; ++b) v[size_t(a * nb + b)] = s * row[b];
  }
  p2_store_.append(v.data());
  const float o = channel_offset(dyn_, 0);
  std::vector<float> sig(static_cast<size_t>(na));
  for (int a = 0; a < na; ++a) {
    double s = 0;
    for (int b = 0; b < nb; ++b) s += v[size_t(a * nb + b)];
    sig[size_t(a)] = float(s / nb) - o;
  }
  p2_lanes_.append(sig.data());
}

void Encoder::cache_i2(uint32_t e) {
  i2_rows_.ids[table_row_hash<uint32_t, uint32_t>(books_.i2, e, nullptr)].push_back(e);
  const int na = grid_.n_alpha, nb = grid_.n_beta, n = na * nb;
  std::vector<float> v(static_cast<size_t>(2 * n));
  for (int a = 0; a < na; ++a) {
    const uint32_t i1 = books_.i2.at(e, size_t(a));
    for (int b = 0; b < nb; ++b) {
      const uint32_t c = books_.i1.at(i1, size_t(b));
      v[size_t(a * nb + b)] = books_.c.at(c, 0);
      v[size_t(n + a * nb + b)] = books_.c.at(c, 1);
    }
  }
  i2_store_.append(v.data());
  std::vector<float> sig;
  for (int ch = 0; ch < 2; ++ch)
    for (int a = 0; a < na; ++a) {
      double s = 0;
      for (int b = 0; b < nb; ++b) s += v[size_t(ch * n + a * nb + b)];
      sig.push_back(float(s / nb) - channel_offset(dyn_, 1 + ch));
    }
  i2_lanes_.append(sig.data());
}

namespace {

// The means of `bands` consecutive bands of n row means, times f: a coarse luminance profile.
void append_bands(const float* rows, int n, int bands, float f, std::vector<float>& out) {
  for (int b = 0; b < bands; ++b) {
    const int first = b * n / bands, last = (b + 1) * n / bands;
    double sum = 0;
    for (int r = first; r < last; ++r) sum += rows[r];
    out.push_back(float(f * (sum / (last - first))));
  }
}

// A plane's (rows x cols, row-major) luminance as `bands` bands of its column means, offset-removed.
void append_column_bands(const float* v, int rows, int cols, int bands, float offset, std::vector<float>& out) {
  std::vector<float> means(static_cast<size_t>(cols));
  for (int c = 0; c < cols; ++c) {
    double sum = 0;
    for (int r = 0; r < rows; ++r) sum += v[r * cols + c];
    means[size_t(c)] = float(sum / rows) - offset;
  }
  append_bands(means.data(), cols, bands, 1.0f, out);
}

}  // namespace

void Encoder::cache_m(uint32_t e) {
  const uint32_t p2 = books_.m.at(e, 0), i2 = books_.m.at(e, 1);
  const int na = grid_.n_alpha;
  const ChannelView y = p2_store_.view(p2, 0);
  const double n = double(g2_.size());
  m_bright_.push_back(float(y.sum / n) - channel_offset(dyn_, 0));
  std::vector<float> sig(static_cast<size_t>(3 * na));  // the P2 plane's row means, then the I2 plane's
  p2_lanes_.row(p2, sig.data());
  i2_lanes_.row(i2, sig.data() + na);
  if (m_bands() > 0) append_column_bands(y.v, na, grid_.n_beta, m_bands(), channel_offset(dyn_, 0), sig);
  m_sig_.append(sig.data());
  m_lookup_.emplace((uint64_t(p2) << 32) | i2, e);
}

// Proxy signatures of composite entries. P3: per plane, the offset-removed luminance mean of each of
// bands_ alpha bands and the chroma means; P4: per plane, the channel means (p3_mean_).
void Encoder::cache_p3(uint32_t e) {
  p3_rows_.ids[table_row_hash(books_.p3_index, e, &books_.p3_scale)].push_back(e);
  const int nt = grid_.n_theta_v, na = grid_.n_alpha;
  double bright = 0;
  std::vector<float> sig;
  for (int t = 0; t < nt; ++t) {
    const uint32_t m = books_.p3_index.at(e, size_t(t));
    const float s = books_.p3_scale.at(e, size_t(t));
    bright += s * m_bright_[m];
    const float* ms = m_sig_.row(m);
    for (int c = 0; c < 3; ++c) {
      const float f = channel_scales(dyn_, c) ? s : 1.0f;
      append_bands(ms + c * na, na, 1, f, p3_mean_);
      if (c == 0) append_bands(ms, na, bands_, f, sig);
      else sig.push_back(p3_mean_.back());
    }
  }
  p3_sig_.append(sig.data());
  p3_bright_.push_back(float(bright / nt));
}

void Encoder::cache_p4(uint32_t e) {
  p4_rows_.ids[table_row_hash(books_.p4_index, e, &books_.p4_scale)].push_back(e);
  const int np = grid_.n_phi_v, nt = grid_.n_theta_v;
  double bright = 0;
  std::vector<float> sig;
  for (int p = 0; p < np; ++p) {
    const uint32_t p3 = books_.p4_index.at(e, size_t(p));
    const float s = books_.p4_scale.at(e, size_t(p));
    bright += s * p3_bright_[p3];
    const float* ps = p3_mean_.data() + size_t(p3) * 3 * size_t(nt);
    for (int i = 0; i < 3 * nt; ++i) sig.push_back(channel_scales(dyn_, i % 3) ? s * ps[i] : ps[i]);
  }
  p4_sig_.append(sig.data());
  p4_bright_.push_back(float(bright / np));
  if (settings_.metric == Metric::MSE) laesa_insert(e);
}

// <a - o, b - o> over the channels an RGB scale acts on, with both planes' factors.
double Encoder::plane_dot(const PlaneRef& a, const PlaneRef& b) const {
  const int n = g2_.size();
  double sum = 0;
  for (int c = 0; c < 3; ++c) {
    if (!channel_scales(dyn_, c)) continue;
    const ChannelView x = c == 0 ? p2_store_.view(a.p2, 0) : i2_store_.view(a.i2, c - 1);
    const ChannelView y = c == 0 ? p2_store_.view(b.p2, 0) : i2_store_.view(b.i2, c - 1);
    const double o = channel_offset(dyn_, c);
    double xy = 0;
    for (int i = 0; i < n; ++i) xy += double(x.v[i]) * y.v[i];
    sum += xy - o * (x.sum + y.sum) + n * o * o;
  }
  return double(a.factor) * double(b.factor) * sum;
}

namespace {
double angle_of(double dot, double na, double nb) {
  if (!(na > 0) || !(nb > 0)) return std::numeric_limits<double>::quiet_NaN();
  return std::acos(std::clamp(dot / (na * nb), -1.0, 1.0));
}
}  // namespace

void Encoder::laesa_insert(uint32_t e) {
  std::vector<PlaneRef> pe, pp;
  planes_of_p4(e, pe);
  double norm2 = 0;
  for (const auto& p : pe) norm2 += plane_dot(p, p);
  p4_norm_.push_back(std::sqrt(std::max(0.0, norm2)));
  pivot_angle_.resize(size_t(e + 1) * kPivots, std::numeric_limits<double>::quiet_NaN());
  double closest = 10;
  for (size_t j = 0; j < pivots_.size(); ++j) {
    planes_of_p4(pivots_[j], pp);
    double d = 0;
    for (size_t i = 0; i < pe.size(); ++i) d += plane_dot(pe[i], pp[i]);
    const double a = angle_of(d, p4_norm_[e], p4_norm_[pivots_[j]]);
    pivot_angle_[size_t(e) * kPivots + j] = a;
    if (std::isfinite(a)) closest = std::min(closest, a);
  }
  // Dynamic LAESA: a new entry far enough from the pivots becomes one while there is room.
  if (int(pivots_.size()) < kPivots && p4_norm_[e] > 0 && closest > 0.05) {
    const size_t j = pivots_.size();
    pivots_.push_back(e);
    for (uint32_t other = 0; other <= e; ++other) {
      planes_of_p4(other, pp);
      double d = 0;
      for (size_t i = 0; i < pe.size(); ++i) d += plane_dot(pp[i], pe[i]);
      pivot_angle_[size_t(other) * kPivots + j] = other == e ? 0.0 : angle_of(d, p4_norm_[other], p4_norm_[e]);
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Searches.

double Encoder::bound_for(double threshold, size_t values) const {
  return dissimilarity_to_score(settings_.metric, threshold, values);
}

void Encoder::planes_of_p3(uint32_t e, std::vector<PlaneRef>& out) const {
  out.clear();
  p3_planes(e, 1.0f, out);
}

void Encoder::planes_of_p4(uint32_t e, std::vector<PlaneRef>& out) const {
  out.clear();
  for (int p = 0; p < grid_.n_phi_v; ++p) p3_planes(books_.p4_index.at(e, size_t(p)), books_.p4_scale.at(e, size_t(p)), out);
}

bool Encoder::evaluate_composite(const Query& q, const PlaneRef* planes, int np, double bound, Ctx& ctx, double* score,
                                 float* scale, bool fixed_scale) const {
  const int n = g2_.size();
  // Best RGB scale: least squares on the offset-removed values of the channels it acts on.
  double num = 0, den = 0;
  for (int j = 0; j < np; ++j) {
    const double f = planes[j].factor;
    for (int c = 0; c < 3; ++c) {
      if (!channel_scales(dyn_, c)) continue;
      const ChannelView& x = q.at(j, c);
      const ChannelView y = c == 0 ? p2_store_.view(planes[j].p2, 0) : i2_store_.view(planes[j].i2, c - 1);
      const double o = channel_offset(dyn_, c);
      const double xy = dot(x.v, y.v, n);
      num += f * (xy - o * (x.sum + y.sum) + n * o * o);
      den += f * f * (y.sumsq - 2 * o * y.sum + n * o * o);
    }
  }
  const double s = fixed_scale ? double(*scale) : den > 1e-20 ? std::max(0.0, num / den) : 1.0;
  ctx.acc.reset(settings_.metric, q.values, settings_.outlier_fraction, bound);
  const bool reorder = settings_.metric == Metric::SSIM && int(q.order.size()) == np;
  for (int jj = 0; jj < np; ++jj)
    for (int c = 0; c < 3; ++c) {
      const int j = reorder ? q.order[size_t(jj)] : jj;
      const ChannelView& x = q.at(j, c);
      const ChannelView y = c == 0 ? p2_store_.view(planes[j].p2, 0) : i2_store_.view(planes[j].i2, c - 1);
      const Affine ax = unit_affine(dyn_, c, q.unit);
      const Affine ay = unit_affine(dyn_, c, float(q.unit * s * planes[j].factor));
      if (!accumulate_channel(g2_, settings_.metric, x, ax, y, ay, ctx.k.c1[c], ctx.k.c2[c], ctx.acc,
                              ctx.scratch.data()))
        return false;
    }
  *score = ctx.acc.score();
  *scale = float(s);
  return true;
}

// evaluate_composite at the composition's own scale s without a bound, with the planes' values
// computed on the pool's threads (a P4 composition has 112 planes) and added in the same order.
double Encoder::composition_score(const Query& q, const std::vector<PlaneRef>& planes, float s, Ctx& ctx) const {
  const int np = int(planes.size()), n = g2_.size();
  const bool ssim = settings_.metric == Metric::SSIM;
  const double scale = s;
  std::vector<float> values(ssim ? size_t(np) * 3 * size_t(n) : 0);
  std::vector<double> error(ssim ? 0 : size_t(np) * 3);
  for_each_plane(np, threads_, ctx.scratch, [&](int j, float* scratch) {
    for (int c = 0; c < 3; ++c) {
      const ChannelView& x = q.at(j, c);
      const ChannelView y = c == 0 ? p2_store_.view(planes[size_t(j)].p2, 0) : i2_store_.view(planes[size_t(j)].i2, c - 1);
      const Affine ax = unit_affine(dyn_, c, q.unit);
      const Affine ay = unit_affine(dyn_, c, float(q.unit * scale * planes[size_t(j)].factor));
      if (ssim) {
        const float* v = ssim_values(g2_, x, ax, y, ay, ctx.k.c1[c], ctx.k.c2[c], scratch);
        std::copy(v, v + n, values.data() + size_t(j * 3 + c) * size_t(n));
      } else {
        error[size_t(j * 3 + c)] = squared_error(n, x, ax, y, ay);
      }
    }
  });
  ctx.acc.reset(settings_.metric, q.values, settings_.outlier_fraction, kNoBound);
  const bool reorder = ssim && int(q.order.size()) == np;
  for (int jj = 0; jj < np; ++jj)
    for (int c = 0; c < 3; ++c) {
      const int j = reorder ? q.order[size_t(jj)] : jj;
      if (ssim) ctx.acc.add_ssim(values.data() + size_t(j * 3 + c) * size_t(n), n);
      else ctx.acc.add_squared_error(error[size_t(j * 3 + c)]);
    }
  return ctx.acc.score();
}

namespace {

// A query over texel planes [first_plane, first_plane + planes) borrowing the parent's statistics.
template <class Q>
Q sub_query(const Q& parent, int first_plane, int planes) {
  Q q;
  q.planes = planes;
  q.first = parent.first;
  q.channels = parent.channels;
  q.unit = parent.unit;
  q.views.assign(parent.views.begin() + first_plane * parent.channels,
                 parent.views.begin() + (first_plane + planes) * parent.channels);
  q.values = parent.values / size_t(parent.planes) * size_t(planes);
  return q;
}

}  // namespace

// Runs a nearest-code-vector search: eval(e, bound, &score, &scale) scores candidate e or returns
// false once it cannot reach `bound`. Ties go to the lowest index, so pruning never changes the result.
template <class Eval>
static void run_search(const std::vector<uint32_t>& order, bool pruning, double threshold_score, Eval eval,
                       EncoderStats& counts, int64_t& best_index, double& best_score, float& best_scale) {
  best_index = -1;
  best_score = kNoBound;
  for (uint32_t e : order) {
    double sc;
    float s = 1;
    ++counts.comparisons;
    const double bound = pruning ? std::max(threshold_score, best_score) : kNoBound;
    if (!eval(e, bound, &sc, &s)) {
      ++counts.pruned;
      continue;
    }
    if (sc > best_score || (sc == best_score && int64_t(e) < best_index)) {
      best_index = e;
      best_score = sc;
      best_scale = s;
    }
  }
  if (best_index >= 0 && best_score < threshold_score) best_index = -1;
}

// A query's proxy signature, as its candidates' (level 4: per plane channel means; 3: the same with
// the luminance in bands_ alpha bands; M: per channel row means and the luminance in m_bands()
// beta bands), offset-removed.
void Encoder::proxy_signature(const Query& q, int level, std::vector<float>& out) const {
  out.clear();
  const int na = grid_.n_alpha, nb = grid_.n_beta;
  auto row_means = [&](const ChannelView& x, int c, float* rows) {
    for (int a = 0; a < na; ++a) rows[a] = float(x.row_sum(a, nb) / nb) - channel_offset(dyn_, c);
  };
  std::vector<float> rows(static_cast<size_t>(na));
  if (level == 2) {
    for (int c = 0; c < 3; ++c) {
      row_means(q.at(0, c), c, rows.data());
      out.insert(out.end(), rows.begin(), rows.end());
    }
    if (m_bands() > 0) append_column_bands(q.at(0, 0).v, na, nb, m_bands(), channel_offset(dyn_, 0), out);
    return;
  }
  for (int p = 0; p < q.planes; ++p)
    for (int c = 0; c < 3; ++c) {
      if (level == 3 && c == 0) {
        row_means(q.at(p, c), c, rows.data());
        append_bands(rows.data(), na, bands_, 1.0f, out);
      } else {
        out.push_back(float(q.at(p, c).sum / g2_.size()) - channel_offset(dyn_, c));
      }
    }
}

const SignatureTable& Encoder::signatures(int level) const { return level == 4 ? p4_sig_ : level == 3 ? p3_sig_ : m_sig_; }

// How many candidates a search of a level scores by proxy order (the rest, without a limit, in
// index order); 0: all of them in index order.
size_t Encoder::proxy_k(int level) const {
  const int limit = settings_.candidate_limit;
  const int k = limit > 0 ? limit : settings_.pruning ? settings_.proxy_candidates : 0;
  return k <= 0 || signatures(level).size() <= size_t(k) ? 0 : size_t(k);
}

void Encoder::prime_orders(const Query& q, int level, int parts, int part_planes, Ctx& ctx) const {
  const size_t k = proxy_k(level);
  if (k == 0) return;
  std::vector<std::vector<float>> sig(static_cast<size_t>(parts));
  std::vector<const float*> qs;
  for (int p = 0; p < parts; ++p) {
    proxy_signature(sub_query(q, p * part_planes, part_planes), level, sig[size_t(p)]);
    qs.push_back(sig[size_t(p)].data());
  }
  std::vector<std::vector<SignatureTable::Neighbour>> near(static_cast<size_t>(parts));
  signatures(level).nearest_many(qs.data(), qs.size(), k, 0, near.data(), threads_);
  for (int p = 0; p < parts; ++p)
    ctx.memo[level - 2][q.views[size_t(p * part_planes * q.channels)].v] = {signatures(level).size(), std::move(near[size_t(p)])};
}

void Encoder::order_composite(const Query& q, int level, Ctx& ctx) const {
  ctx.order.clear();
  const SignatureTable& sig = signatures(level);
  const uint32_t n = uint32_t(sig.size());
  if (n == 0) return;
  const size_t k = proxy_k(level);
  if (k == 0) {
    for (uint32_t e = 0; e < n; ++e) ctx.order.push_back(e);
    return;
  }
  std::vector<float> qsig;
  proxy_signature(q, level, qsig);
  // The k nearest by proxy: from the composition's one pass over the table plus the entries added
  // since, or a scan of its own.
  Ctx::Memo* memo = nullptr;
  if (level < 4)
    if (auto it = ctx.memo[level - 2].find(q.views[0].v); it != ctx.memo[level - 2].end()) memo = &it->second;
  if (memo) {
    sig.extend(qsig.data(), k, memo->end, memo->near);
    memo->end = n;
    for (const auto& c : memo->near) ctx.order.push_back(c.e);
  } else {
    sig.nearest(qsig.data(), k, ctx.order, threads_);
  }
  if (settings_.candidate_limit > 0) return;
  // Without a limit, the others in index order.
  ctx.tried.assign(n, 0);
  for (uint32_t e : ctx.order) ctx.tried[e] = 1;
  for (uint32_t e = 0; e < n; ++e)
    if (!ctx.tried[e]) ctx.order.push_back(e);
}

Encoder::Match Encoder::search_composite(const Query& q, int level, double threshold_score, Ctx& ctx) const {
  order_composite(q, level, ctx);
  const std::vector<uint32_t> order = ctx.order;
  return search_composite_in(q, level, order, threshold_score, ctx);
}

Encoder::Match Encoder::search_composite_in(const Query& q, int level, const std::vector<uint32_t>& order,
                                            double threshold_score, Ctx& ctx, size_t threads) const {
  Match best;
  if (order.empty()) return best;
  std::vector<PlaneRef> planes;  // of the pivots
  // LAESA (MSE only): angles of the query to the pivots bound every candidate's residual from below.
  // Each pivot's angle costs one whole comparison: not worth it for a few candidates (a settled batch).
  const bool laesa = level == 4 && settings_.metric == Metric::MSE && settings_.pruning && !pivots_.empty() &&
                     order.size() > pivots_.size();
  double qnorm2 = 0;
  std::vector<double> qangle;
  if (laesa) {
    const int n = g2_.size();
    for (int p = 0; p < q.planes; ++p)
      for (int c = 0; c < 3; ++c) {
        if (!channel_scales(dyn_, c)) continue;
        const ChannelView& x = q.at(p, c);
        const double o = channel_offset(dyn_, c);
        qnorm2 += x.sumsq - 2 * o * x.sum + n * o * o;
      }
    for (uint32_t pv : pivots_) {
      planes_of_p4(pv, planes);
      double d = 0;
      for (int p = 0; p < q.planes; ++p)
        for (int c = 0; c < 3; ++c) {
          if (!channel_scales(dyn_, c)) continue;
          const ChannelView& x = q.at(p, c);
          const ChannelView y = c == 0 ? p2_store_.view(planes[size_t(p)].p2, 0) : i2_store_.view(planes[size_t(p)].i2, c - 1);
          const double o = channel_offset(dyn_, c);
          double xy = 0;
          for (int i = 0; i < n; ++i) xy += double(x.v[i]) * y.v[i];
          d += planes[size_t(p)].factor * (xy - o * (x.sum + y.sum) + n * o * o);
        }
      qangle.push_back(angle_of(d, std::sqrt(std::max(0.0, qnorm2)), p4_norm_[pv]));
    }
  }
  const double kHalfPi = 1.5707963267948966;
  auto eval = [&](Ctx& c, std::vector<PlaneRef>& planes, uint32_t e, double bound, double* sc, float* s) {
    if (laesa && bound > kNoBound) {
      double lb = 0;
      for (size_t j = 0; j < qangle.size(); ++j) {
        const double pa = pivot_angle_[size_t(e) * kPivots + j];
        if (std::isfinite(pa) && std::isfinite(qangle[j])) lb = std::max(lb, std::abs(qangle[j] - pa));
      }
      lb = std::min(std::max(0.0, lb - 1e-6), kHalfPi);
      const double residual = qnorm2 * std::sin(lb) * std::sin(lb) * (1.0 - 1e-5);  // safety margin for rounding
      if (-residual < bound) {
        ++c.counts.laesa_skipped;
        return false;
      }
    }
    if (level == 4) planes_of_p4(e, planes);
    else if (level == 3) planes_of_p3(e, planes);
    else planes.assign(1, PlaneRef{books_.m.at(e, 0), books_.m.at(e, 1), 1.0f});
    return evaluate_composite(q, planes.data(), int(planes.size()), bound, c, sc, s);
  };
  // Candidates are spread over the threads when there are planes enough to pay for the hand-over
  // (a P4 candidate is 112 planes, P3 7, M 1: an M search goes parallel with a full candidate list
  // only). The result is the best candidate whatever the order they are scored in (ties to the
  // lowest index), and a bound found by any thread prunes only candidates that cannot win, so it
  // equals the sequential search.
  const bool worth = order.size() > 1 && order.size() * size_t(q.planes) >= kParallelPlanes;
  const size_t slots = threads > 1 && worth ? parallel_slots(order.size(), {threads, 1}) : 1;
  if (slots == 1) {
    run_search(order, settings_.pruning, threshold_score,
               [&](uint32_t e, double bound, double* sc, float* s) { return eval(ctx, planes, e, bound, sc, s); },
               ctx.counts, best.index, best.score, best.scale);
    return best;
  }
  struct Slot {
    Ctx ctx;
    std::vector<PlaneRef> planes;
    Match best;
  };
  std::vector<Slot> slot(slots);
  for (Slot& w : slot) {
    w.ctx.k = ctx.k;
    w.ctx.scratch.resize(ctx.scratch.size());
    w.best.score = kNoBound;
  }
  std::atomic<double> found{kNoBound};  // the best score any thread has: a bound for all
  parallel_for(0, order.size(), [&](size_t first, size_t last, size_t k) {
    Slot& w = slot[k];
    for (size_t i = first; i < last; ++i) {
      const uint32_t e = order[i];
      double sc;
      float sl = 1;
      ++w.ctx.counts.comparisons;
      const double bound = settings_.pruning ? std::max(threshold_score, found.load(std::memory_order_relaxed)) : kNoBound;
      if (!eval(w.ctx, w.planes, e, bound, &sc, &sl)) {
        ++w.ctx.counts.pruned;
        continue;
      }
      if (sc > w.best.score || (sc == w.best.score && int64_t(e) < w.best.index)) w.best = {int64_t(e), sc, sl};
      for (double f = found.load(); sc > f && !found.compare_exchange_weak(f, sc);) {
      }
    }
  }, ParallelOptions{threads, 1});
  best.score = kNoBound;
  for (const Slot& w : slot) {
    ctx.counts.add(w.ctx.counts);
    if (w.best.index >= 0 && (w.best.score > best.score || (w.best.score == best.score && w.best.index < best.index)))
      best = w.best;
  }
  if (best.index >= 0 && best.score < threshold_score) best.index = -1;
  return best;
}

// The growing phases search a composition's parts one after the other, as a part that misses inserts
// entries the next parts may pick. Most parts find a match, and the entries inserted before a part
// change its search only by themselves: so every part's first search runs at once against the
// code-books as they are (one part per thread, the grain that pays for these small searches), and
// confirm() adds what the parts before it inserted. Empty with one thread: the plain searches then.
std::vector<Encoder::Speculation> Encoder::speculate(const std::vector<Query>& parts, int level, double threshold,
                                                     Ctx& ctx) const {
  std::vector<Speculation> spec;
  if (threads_ <= 1 || parts.size() < 2) return spec;
  spec.resize(parts.size());
  for (size_t k = 0; k < parts.size(); ++k) {
    order_composite(parts[k], level, ctx);
    spec[k].order = ctx.order;
    spec[k].end = signatures(level).size();
  }
  std::vector<Ctx>& slot = side_contexts(ctx, parallel_slots(parts.size(), {threads_, 1}));
  parallel_for(0, parts.size(), [&](size_t first, size_t last, size_t w) {
    for (size_t k = first; k < last; ++k)
      spec[k].best = search_composite_in(parts[k], level, spec[k].order, bound_for(threshold, parts[k].values),
                                         slot[w], 1);
  }, ParallelOptions{threads_, 1});
  collect_side_counts(ctx);
  ctx.counts.ahead += parts.size();
  return spec;
}

namespace {
// Rows a thread searches ahead per window (rows_ahead): a row that inserts costs the searches of
// the window's rows after it, which are made again.
constexpr int kRowsAheadPerThread = 2;
}  // namespace

template <class Size, class Search, class Commit>
void Encoder::rows_ahead(int n, Ctx& ctx, Size size, Search search, Commit commit) {
  if (threads_ <= 1) {
    for (int a = 0; a < n; ++a) commit(a, search(a, ctx));
    return;
  }
  const int window = kRowsAheadPerThread * int(threads_);
  std::vector<Match> found(static_cast<size_t>(window));
  for (int a = 0; a < n;) {
    const int w = std::min(window, n - a);
    std::vector<Ctx>& side = side_contexts(ctx, parallel_slots(size_t(w), {threads_, 1}));
    parallel_for(0, size_t(w), [&](size_t first, size_t last, size_t slot) {
      for (size_t i = first; i < last; ++i) found[i] = search(a + int(i), side[slot]);
    }, ParallelOptions{threads_, 1});
    collect_side_counts(ctx);
    const size_t before = size();
    int done = 0;
    while (done < w) {
      commit(a + done, found[size_t(done)]);
      ++done;
      if (size() != before) break;
    }
    ctx.counts.rows_ahead += size_t(w);
    ctx.counts.rows_redone += size_t(w - done);
    a += done;
  }
}

// The search of q now, from its speculative one. The order now is the k nearest of the entries the
// speculation saw and those added since (the memo's exact extension), so every old entry in it was
// in the speculation's order: if the speculation's winner is still in it, the best of the order is
// the better of that winner and the added entries (ties go to the lower index, the old winner's).
// Should the winner have been pushed out, the order is searched again.
Encoder::Match Encoder::confirm(const Query& q, int level, double bound, const Speculation& s, Ctx& ctx) const {
  if (signatures(level).size() == s.end) return s.best;
  order_composite(q, level, ctx);
  const std::vector<uint32_t> order = ctx.order;
  if (s.best.index >= 0 && std::find(order.begin(), order.end(), uint32_t(s.best.index)) == order.end()) {
    ++ctx.counts.ahead_redone;
    return search_composite_in(q, level, order, bound, ctx);
  }
  std::vector<uint32_t> added;
  for (uint32_t e : order)
    if (e >= s.end) added.push_back(e);
  const double floor = s.best.index >= 0 ? std::max(bound, s.best.score) : bound;
  if (added.empty()) return s.best;
  ++ctx.counts.ahead_extended;
  const Match m = search_composite_in(q, level, added, floor, ctx);
  return m.index >= 0 && (s.best.index < 0 || m.score > s.best.score) ? m : s.best;
}

// The candidate order of a P2 or I2 search, by the plain distance of the row means: the k =
// max(proxy_candidates, candidate_limit) nearest first, then the others in index order; with a
// limit, only the `limit` nearest (an approximate search, see docs/similarity.md). The nearest are
// the k smallest by (distance, index), kept in one pass (a bounded heap turns most entries away
// with one comparison; the scans cover every entry, up to 130k at 256 x 256), on the pool's threads
// when there are entries enough (the same order: RowLanes::nearest).
void Encoder::order_by_rows(const float* qsig, const RowLanes& rows, Ctx& ctx) const {
  const uint32_t n = uint32_t(rows.size());
  const int limit = settings_.candidate_limit;
  const size_t k = size_t(std::max(settings_.pruning ? settings_.proxy_candidates : 0, std::max(limit, 0)));
  std::vector<uint32_t>& order = ctx.order;
  order.clear();
  if (k == 0 || n <= k) {
    for (uint32_t e = 0; e < n; ++e) order.push_back(e);
    return;
  }
  thread_local std::vector<Ranked> best;
  rows.nearest(qsig, k, threads_, best);
  for (const Ranked& r : best) order.push_back(r.e);
  if (limit > 0) {
    order.resize(size_t(limit));
    return;
  }
  ctx.tried.assign(n, 0);
  for (uint32_t e : order) ctx.tried[e] = 1;
  for (uint32_t e = 0; e < n; ++e)
    if (!ctx.tried[e]) order.push_back(e);
}

Encoder::Match Encoder::search_p2(const Query& q, double threshold_score, Ctx& ctx) const {
  Match best;
  const uint32_t n = p2_store_.size();
  if (n == 0) return best;
  const int na = grid_.n_alpha, nb = grid_.n_beta;
  std::vector<float> qsig(static_cast<size_t>(na));
  for (int a = 0; a < na; ++a) qsig[size_t(a)] = float(q.at(0, 0).row_sum(a, nb) / nb) - channel_offset(dyn_, 0);
  order_by_rows(qsig.data(), p2_lanes_, ctx);
  const Affine ax = unit_affine(dyn_, 0, q.unit);
  auto eval = [&](uint32_t e, double bound, double* sc, float* s) {
    ctx.acc.reset(settings_.metric, q.values, settings_.outlier_fraction, bound);
    if (!accumulate_channel(g2_, settings_.metric, q.at(0, 0), ax, p2_store_.view(e, 0), ax, ctx.k.c1[0],
                            ctx.k.c2[0], ctx.acc, ctx.scratch.data()))
      return false;
    *sc = ctx.acc.score();
    *s = 1;
    return true;
  };
  const std::vector<uint32_t> order = ctx.order;
  run_search(order, settings_.pruning, threshold_score, eval, ctx.counts, best.index, best.score, best.scale);
  return best;
}

Encoder::Match Encoder::search_i2(const Query& q, double threshold_score, Ctx& ctx) const {
  Match best;
  const uint32_t n = i2_store_.size();
  if (n == 0) return best;
  const int na = grid_.n_alpha, nb = grid_.n_beta;
  std::vector<float> qsig;
  for (int c = 1; c <= 2; ++c)
    for (int a = 0; a < na; ++a) qsig.push_back(float(q.at(0, c).row_sum(a, nb) / nb) - channel_offset(dyn_, c));
  order_by_rows(qsig.data(), i2_lanes_, ctx);
  auto eval = [&](uint32_t e, double bound, double* sc, float* s) {
    ctx.acc.reset(settings_.metric, q.values, settings_.outlier_fraction, bound);
    for (int c = 1; c <= 2; ++c) {
      const Affine a = unit_affine(dyn_, c, q.unit);
      if (!accumulate_channel(g2_, settings_.metric, q.at(0, c), a, i2_store_.view(e, c - 1), a, ctx.k.c1[c],
                              ctx.k.c2[c], ctx.acc, ctx.scratch.data()))
        return false;
    }
    *sc = ctx.acc.score();
    *s = 1;
    return true;
  };
  const std::vector<uint32_t> order = ctx.order;
  run_search(order, settings_.pruning, threshold_score, eval, ctx.counts, best.index, best.score, best.scale);
  return best;
}

float Encoder::p1_scale(const float* x, uint32_t e) const {
  const ChannelView y = p1_store_.view(e, 0);
  return y.sumsq > 0 ? float(std::max(0.0, double(dot(x, y.v, grid_.n_beta)) / y.sumsq)) : 0.0f;
}

Encoder::Match Encoder::search_p1(const float* row, float unit, double threshold_score, Ctx& ctx) const {
  Match best;
  const uint32_t n = p1_store_.size();
  if (n == 0) return best;
  const int nb = grid_.n_beta;
  float mean[64], var[64];
  std::vector<float> own;
  float* pm = mean;
  float* pv = var;
  if (nb > 64) {
    own.resize(size_t(2 * nb));
    pm = own.data();
    pv = own.data() + nb;
  }
  const ChannelView x = make_view(g1_, row, pm, pv);
  const Affine ax = unit_affine(dyn_, 0, unit);
  const float o = channel_offset(dyn_, 0);
  if (indexed_1d()) {
    float shape[256];
    unit_shape(row, nb, shape);
    p1_index_.nearest(shape, settings_.candidate_limit, kProbes, ctx.order);
  } else {
    ctx.order.resize(n);
    for (uint32_t e = 0; e < n; ++e) ctx.order[e] = e;
  }
  // P1 rows are densities: the P2 scale multiplies Y itself (offset included), so the best scale
  // is the raw least-squares one.
  // With r = 0 (fewer than 50 samples per row) the score is the minimum: stop at the first value
  // below the bound. Same values as the general path, so the same choices.
  const bool minimum = settings_.metric == Metric::SSIM && g1_.radius() == 1 &&
                       size_t(std::floor(settings_.outlier_fraction * double(nb) + 1e-9)) == 0;
  auto eval = [&](uint32_t e, double bound, double* sc, float* s) {
    const ChannelView y = p1_store_.view(e, 0);
    const double sy = y.sumsq > 0 ? std::max(0.0, double(dot(x.v, y.v, nb)) / y.sumsq) : 0.0;
    const Affine ay{o * (1.0f - unit), float(unit * sy)};
    if (minimum) {
      *s = float(sy);
      return min_ssim_row(g1_, x, ax, y, ay, ctx.k.c1[0], ctx.k.c2[0], bound, sc);
    }
    ctx.acc.reset(settings_.metric, size_t(nb), settings_.outlier_fraction, bound);
    if (!accumulate_channel(g1_, settings_.metric, x, ax, y, ay, ctx.k.c1[0], ctx.k.c2[0], ctx.acc,
                            ctx.scratch.data()))
      return false;
    *sc = ctx.acc.score();
    *s = float(sy);
    return true;
  };
  const std::vector<uint32_t> order = ctx.order;
  run_search(order, settings_.pruning, threshold_score, eval, ctx.counts, best.index, best.score, best.scale);
  return best;
}

Encoder::Match Encoder::search_i1(const float* row, float unit, double threshold_score, Ctx& ctx) const {
  Match best;
  const uint32_t n = i1_store_.size();
  if (n == 0) return best;
  const int nb = grid_.n_beta;
  std::vector<float> st(static_cast<size_t>(4 * nb));
  const ChannelView xa = make_view(g1_, row, st.data(), st.data() + nb);
  const ChannelView xb = make_view(g1_, row + nb, st.data() + 2 * nb, st.data() + 3 * nb);
  const Affine a1 = unit_affine(dyn_, 1, unit), a2 = unit_affine(dyn_, 2, unit);
  if (indexed_1d()) {
    i1_index_.nearest(row, settings_.candidate_limit, kProbes, ctx.order);
  } else {
    ctx.order.resize(n);
    for (uint32_t e = 0; e < n; ++e) ctx.order[e] = e;
  }
  auto eval = [&](uint32_t e, double bound, double* sc, float* s) {
    ctx.acc.reset(settings_.metric, size_t(2 * nb), settings_.outlier_fraction, bound);
    if (!accumulate_channel(g1_, settings_.metric, xa, a1, i1_store_.view(e, 0), a1, ctx.k.c1[1], ctx.k.c2[1],
                            ctx.acc, ctx.scratch.data()))
      return false;
    if (!accumulate_channel(g1_, settings_.metric, xb, a2, i1_store_.view(e, 1), a2, ctx.k.c1[2], ctx.k.c2[2],
                            ctx.acc, ctx.scratch.data()))
      return false;
    *sc = ctx.acc.score();
    *s = 1;
    return true;
  };
  const std::vector<uint32_t> order = ctx.order;
  run_search(order, settings_.pruning, threshold_score, eval, ctx.counts, best.index, best.score, best.scale);
  return best;
}

// ---------------------------------------------------------------------------------------------
// Encoding, top-down with bottom-up insertion.

P6Entry Encoder::encode_growing(const float* texel) {
  sync();
  Ctx ctx;
  const Match m = encode_p4(texel, ctx);
  stats_.add(ctx.counts);  // the search counts: ctx inserts nothing
  stats_.texels += 1;
  P6Entry r;
  r.index = uint32_t(m.index);
  r.scale = m.scale;
  r.dissimilarity = score_to_dissimilarity(settings_.metric, m.score, size_t(3) * grid_.samples());
  return r;
}

namespace {

// The texel with luminance clamped at black: 0 for HDR, the studio-swing 16 for LDR. Below black
// an RGB scale would turn (Y - 16) negative; normalizing such a slice amplifies the overshoot of the
// interpolation into negative densities in P1 (and ruins the range of the P1 quantizer).
void clamp_texel(const float* texel, size_t samples, Dynamic dyn, std::vector<float>& t) {
  t.assign(texel, texel + 3 * samples);
  const float black = channel_offset(dyn, 0);
  for (size_t i = 0; i < samples; ++i) t[i] = std::max(black, t[i]);
}

std::vector<float> clamped_texel(const float* texel, size_t samples, Dynamic dyn) {
  std::vector<float> t;
  clamp_texel(texel, samples, dyn, t);
  return t;
}

float luminance_range(const float* texel, size_t samples) {
  float m = 0;
  for (size_t i = 0; i < samples; ++i) m = std::max(m, texel[i]);
  return m > 0 ? m : 1.0f;
}

}  // namespace

// Compositions are checked at the scale they were composed with: every child's SSIM values are then
// the parent's own values (windows never cross planes), and the parent's percentile counts the
// children's failing values together. So a composition of children that meet the parent's threshold
// meets it too (floor(0.02 a) + floor(0.02 b) <= floor(0.02 (a + b)); paper 4.4.2). Children are
// first encoded at their own, looser thresholds (more reuse); when the composition misses, the part
// with the most failing values is encoded again with the parent's threshold as a cap, until it
// passes -- at most once per part, and only the parts that need it (no compounding retries). The
// rows of a 2D plane (P1 rows in P2, I1 rows in I2) and the samples of a row (C values in I1) are
// compared with other windows than their parent's; those are repaired with exact parts
// (repair_parts).

double Encoder::threshold(double level, double cap) { return std::min(level, cap); }

// Per part, how badly the composition (planes at scale s against q) misses `bound`: SSIM, the number
// of values below it; MSE, the squared error. Parts are runs of `part_planes` planes, or for a single
// M plane its luminance (part 0) and chroma (part 1). Returns whether the whole passes.
bool Encoder::failing_parts(const Query& q, const PlaneRef* planes, int np, int part_planes, float s, double bound,
                            Ctx& ctx, std::vector<double>& bad) const {
  const int n = g2_.size();
  const int parts = part_planes > 0 ? np / part_planes : 2;
  std::vector<double> miss(size_t(np) * 3);
  for_each_plane(np, threads_, ctx.scratch, [&](int j, float* scratch) {
    for (int c = 0; c < 3; ++c) {
      const ChannelView& x = q.at(j, c);
      const ChannelView y = c == 0 ? p2_store_.view(planes[j].p2, 0) : i2_store_.view(planes[j].i2, c - 1);
      const Affine ax = unit_affine(dyn_, c, q.unit), ay = unit_affine(dyn_, c, float(q.unit * s * planes[j].factor));
      double b = 0;
      if (settings_.metric == Metric::MSE) {
        b = squared_error(n, x, ax, y, ay);
      } else {
        const float* v = ssim_values(g2_, x, ax, y, ay, ctx.k.c1[c], ctx.k.c2[c], scratch);
        for (int i = 0; i < n; ++i) b += double(v[i]) < bound ? 1.0 : 0.0;
      }
      miss[size_t(j * 3 + c)] = b;
    }
  });
  // Summed in plane order, whatever thread counted a plane.
  bad.assign(size_t(parts), 0.0);
  double total = 0;
  for (int j = 0; j < np; ++j)
    for (int c = 0; c < 3; ++c) {
      const double b = miss[size_t(j * 3 + c)];
      bad[size_t(part_planes > 0 ? j / part_planes : (c == 0 ? 0 : 1))] += b;
      total += b;
    }
  if (settings_.metric == Metric::MSE) return -total >= bound;
  return total <= std::floor(settings_.outlier_fraction * double(q.values) + 1e-9);
}

// The part to encode again: the worst one not capped yet, or -1 when every failing part is capped.
int Encoder::worst_part(const std::vector<double>& bad, const std::vector<uint8_t>& capped) {
  int worst = -1;
  for (size_t k = 0; k < bad.size(); ++k)
    if (!capped[k] && bad[k] > 0 && (worst < 0 || bad[k] > bad[size_t(worst)])) worst = int(k);
  return worst;
}

// The step P4 and P3 share: `n` parts (P3 or M matches) composed at the normalized brightness
// (the parts' scales divided by it), checked as a whole against `bound`; while it misses, the worst
// part not capped yet is encoded again by encode_part(k, repair_cap). planes_of(entry, factor, out)
// appends a part's planes; `bright` holds the part code-book's brightness per entry.
template <class EncodePart, class PlanesOf>
Encoder::Composite Encoder::compose(const Query& q, const std::vector<Query>& parts, int part_planes, int level,
                                    double part_threshold, const std::vector<float>& bright, double bound,
                                    double repair_cap, Ctx& ctx, EncodePart encode_part, PlanesOf planes_of) {
  const int n = int(parts.size());
  std::vector<Match> part(static_cast<size_t>(n));
  const std::vector<Speculation> spec = speculate(parts, level, part_threshold, ctx);
  for (int k = 0; k < n; ++k)
    part[size_t(k)] = encode_part(k, kNoCap, spec.empty() ? nullptr : &spec[size_t(k)]);
  Composite c;
  c.index.resize(size_t(n));
  c.scale.resize(size_t(n));
  std::vector<double> bad;
  std::vector<uint8_t> capped(static_cast<size_t>(n), 0);
  for (;;) {
    double b = 0;
    for (const Match& m : part) b += m.scale * bright[size_t(m.index)];
    c.norm = normalization(b / n);
    c.planes.clear();
    for (int k = 0; k < n; ++k) {
      c.index[size_t(k)] = uint32_t(part[size_t(k)].index);
      c.scale[size_t(k)] = part[size_t(k)].scale / c.norm;
      planes_of(c.index[size_t(k)], c.scale[size_t(k)], c.planes);
    }
    if (failing_parts(q, c.planes.data(), int(c.planes.size()), part_planes, c.norm, bound, ctx, bad)) break;
    const int w = worst_part(bad, capped);
    if (w < 0) break;  // every failing part meets the threshold on its own: rounding
    const CauseScope<Cause> cause(cause_, kRetry);
    part[size_t(w)] = encode_part(w, repair_cap, nullptr);
    capped[size_t(w)] = 1;
    ++ctx.counts.fallbacks;
  }
  c.score = composition_score(q, c.planes, c.norm, ctx);
  return c;
}

Encoder::Match Encoder::encode_p4(const float* texel_in, Ctx& ctx) {
  const std::vector<float> texel = clamped_texel(texel_in, grid_.samples(), dyn_);
  const Query q = texel_query(texel, ctx);
  const int n = g2_.size(), nt = grid_.n_theta_v;
  const double bound = bound_for(thresholds_.p4, q.values);
  const Match found = search_composite(q, 4, bound, ctx);
  if (found.index >= 0) return found;
  prime_orders(q, 3, grid_.n_phi_v, nt, ctx);
  std::vector<Query> parts;
  for (int p = 0; p < grid_.n_phi_v; ++p) {
    parts.push_back(sub_query(q, p * nt, nt));
    parts.back().order_planes(n);
  }
  const Composite c = compose(
      q, parts, nt, 3, thresholds_.p3, p3_bright_, bound, thresholds_.p4, ctx,
      [&](int p, double cap, const Speculation* spec) { return encode_p3(parts[size_t(p)], ctx, cap, spec); },
      [&](uint32_t p3, float factor, std::vector<PlaneRef>& out) { p3_planes(p3, factor, out); });
  return {int64_t(store_p4(c.index.data(), c.scale.data())), c.score, c.norm};
}

void Encoder::m_planes(const uint32_t* m, const float* scale, float factor, std::vector<PlaneRef>& out) const {
  for (int t = 0; t < grid_.n_theta_v; ++t)
    out.push_back({books_.m.at(m[t], 0), books_.m.at(m[t], 1), factor * scale[t]});
}

void Encoder::p3_planes(uint32_t p3, float factor, std::vector<PlaneRef>& out) const {
  m_planes(books_.p3_index.row(p3), books_.p3_scale.row(p3), factor, out);
}

uint32_t Encoder::store_p4(const uint32_t* p3, const float* scale) {
  return insert_row(CodebookId::P4, p4_rows_, books_.p4_index, p3, &books_.p4_scale, scale, false);
}

Encoder::Match Encoder::encode_p3(const Query& q, Ctx& ctx, double cap, const Speculation* spec) {
  const double t3 = threshold(thresholds_.p3, cap);
  const double bound = bound_for(t3, q.values);
  const Match found = spec ? confirm(q, 3, bound, *spec, ctx) : search_composite(q, 3, bound, ctx);
  if (found.index >= 0) return found;
  prime_orders(q, 2, grid_.n_theta_v, 1, ctx);
  std::vector<Query> parts;
  for (int t = 0; t < grid_.n_theta_v; ++t) parts.push_back(sub_query(q, t, 1));
  const Composite c = compose(
      q, parts, 1, 2, thresholds_.m, m_bright_, bound, t3, ctx,
      [&](int t, double part_cap, const Speculation* part_spec) {
        return encode_m(parts[size_t(t)], ctx, part_cap, part_spec);
      },
      [&](uint32_t m, float factor, std::vector<PlaneRef>& out) {
        out.push_back({books_.m.at(m, 0), books_.m.at(m, 1), factor});
      });
  const uint32_t e = insert_row(CodebookId::P3, p3_rows_, books_.p3_index, c.index.data(), &books_.p3_scale, c.scale.data(), false);
  return {int64_t(e), c.score, c.norm};
}

Encoder::Match Encoder::encode_m(const Query& q, Ctx& ctx, double cap, const Speculation* spec) {
  const double tm = threshold(thresholds_.m, cap);
  const double bound = bound_for(tm, q.values);
  const Match found = spec ? confirm(q, 2, bound, *spec, ctx) : search_composite(q, 2, bound, ctx);
  if (found.index >= 0) return found;
  // Normalize the slice to the fixed brightness, so that P2 and I2 entries are shared across
  // brightness; the parent's scale restores it. Comparisons below stay in absolute units.
  const int n = g2_.size();
  const float o0 = channel_offset(dyn_, 0);
  const double bright = q.at(0, 0).sum / n - o0;
  // Slices darker than 1% of the target stay as they are: normalizing them would amplify their
  // chroma noise (LDR chroma scales with RGB) far outside the usual range of C.
  const float norm = bright >= 0.01 * normalized_brightness(dyn_) ? float(bright) / normalized_brightness(dyn_) : 1.0f;
  std::vector<float> v(static_cast<size_t>(3 * n)), st(static_cast<size_t>(6 * n));
  for (int c = 0; c < 3; ++c) {
    const float* x = q.at(0, c).v;
    const float o = channel_offset(dyn_, c);
    float* out = v.data() + size_t(c * n);
    if (channel_scales(dyn_, c))
      for (int i = 0; i < n; ++i) out[i] = o + (x[i] - o) / norm;
    else
      std::copy(x, x + n, out);
  }
  Query lq, cq;
  lq.planes = cq.planes = 1;
  lq.first = 0;
  lq.channels = 1;
  cq.first = 1;
  cq.channels = 2;
  lq.unit = cq.unit = q.unit * norm;
  lq.values = size_t(n);
  cq.values = size_t(2 * n);
  for (int c = 0; c < 3; ++c) {
    const ChannelView cv = make_view(g2_, v.data() + size_t(c * n), st.data() + size_t(2 * c * n),
                                     st.data() + size_t((2 * c + 1) * n));
    (c == 0 ? lq : cq).views.push_back(cv);
  }
  uint32_t halves[2] = {encode_p2(lq, ctx, kNoCap), encode_i2(cq, ctx, kNoCap)};
  std::vector<double> bad;
  std::vector<uint8_t> capped(2, 0);
  for (;;) {
    const PlaneRef plane{halves[0], halves[1], 1.0f};
    if (failing_parts(q, &plane, 1, 0, norm, bound, ctx, bad)) break;
    const int w = worst_part(bad, capped);
    if (w < 0) break;
    const CauseScope<Cause> cause(cause_, kRetry);
    halves[w] = w == 0 ? encode_p2(lq, ctx, tm) : encode_i2(cq, ctx, tm);
    capped[size_t(w)] = 1;
    ++ctx.counts.fallbacks;
  }
  const PlaneRef plane{halves[0], halves[1], 1.0f};
  double score;
  float s = norm;
  evaluate_composite(q, &plane, 1, kNoBound, ctx, &score, &s, true);
  const uint64_t key = (uint64_t(halves[0]) << 32) | halves[1];
  if (const auto it = m_lookup_.find(key); it != m_lookup_.end()) {
    ++stats_.reused[CodebookId::M];
    return {int64_t(it->second), score, s};
  }
  books_.m.append(halves);
  cache_m(uint32_t(books_.m.rows() - 1));
  count_insert(CodebookId::M, false);
  return {int64_t(books_.m.rows() - 1), score, s};
}

// A composition made of parts -- the rows of a plane of g (by_column false) or the samples of a
// row (true) -- in channels [first, first + nc): the slice x and its composition y (absolute units
// via `unit`) checked against `bound`. While it misses, the worst part that is not exact yet (the
// largest squared error among the parts under a window that holds a failing value) is first offered
// to reuse(part, badness) -- which may put a stored alternative into y if it lowers badness(), the
// composition's failing values (or squared error) -- and, once that has been tried, to
// make_exact(part), which rewrites that part of y exactly. An exact part reproduces the slice, so
// this ends after at most two repairs per part.
template <class Reuse, class MakeExact>
void Encoder::repair_parts(const WindowGeometry& g, bool by_column, const ChannelView* x, int first, int nc,
                           float unit, float* y, std::vector<uint8_t>& exact, double bound, Ctx& ctx, Reuse reuse,
                           MakeExact make_exact) {
  const int cols = g.cols(), n = g.size(), parts = by_column ? g.cols() : g.rows();
  std::vector<float> st(static_cast<size_t>(2 * n * nc));
  std::vector<double> err(static_cast<size_t>(parts));
  std::vector<uint8_t> involved(static_cast<size_t>(parts)), tried(static_cast<size_t>(parts), 0);
  const size_t total = size_t(n) * size_t(nc);
  const double allowed = std::floor(settings_.outlier_fraction * double(total) + 1e-9);
  const bool mse = settings_.metric == Metric::MSE;
  // Failing values (SSIM) or the squared error (MSE) of y, marking the parts under failing windows.
  auto badness = [&]() {
    std::fill(involved.begin(), involved.end(), 0);
    double bad = 0;
    for (int c = 0; c < nc; ++c) {
      const Affine a = unit_affine(dyn_, first + c, unit);
      const float* yc = y + size_t(c * n);
      if (mse) {
        for (int i = 0; i < n; ++i) {
          const float d = a.b * (x[c].v[i] - yc[i]);
          bad += double(d) * d;
        }
        continue;
      }
      const ChannelView yv = make_view(g, yc, st.data() + size_t(2 * c * n), st.data() + size_t((2 * c + 1) * n));
      const float* v = ssim_values(g, x[c], a, yv, a, ctx.k.c1[first + c], ctx.k.c2[first + c], ctx.scratch.data());
      for (int i = 0; i < n; ++i)
        if (double(v[i]) < bound) {
          bad += 1;
          const int at = by_column ? i % cols : i / cols;
          for (int k = std::max(0, at - g.radius()); k <= std::min(parts - 1, at + g.radius()); ++k) involved[size_t(k)] = 1;
        }
    }
    return bad;
  };
  for (;;) {
    const double bad = badness();
    if (mse ? -bad >= bound : bad <= allowed) return;
    int worst = -1;
    for (int k = 0; k < parts; ++k) {
      if (exact[size_t(k)] || (!mse && !involved[size_t(k)])) continue;
      double e = 0;
      for (int c = 0; c < nc; ++c)
        for (int i = 0; i < n; ++i)
          if ((by_column ? i % cols : i / cols) == k) {
            const double d = x[c].v[i] - y[size_t(c * n + i)];
            e += d * d;
          }
      err[size_t(k)] = e;
      if (worst < 0 || e > err[size_t(worst)]) worst = k;
    }
    if (worst < 0) return;  // every involved part is exact: what remains is rounding
    ++ctx.counts.fallbacks;
    if (!tried[size_t(worst)]) {
      tried[size_t(worst)] = 1;
      if (reuse(worst, bad, badness)) continue;
    }
    make_exact(worst);
    exact[size_t(worst)] = 1;
  }
}

// The best of `candidates` for one part of a composition by the composition's own measure:
// try(e) puts candidate e into the composition, badness() measures it, restore() puts the part back.
// Keeps the best (fewest failing values; ties to the earlier candidate) if it beats `now`.
template <class Try, class Badness, class Restore>
bool keep_best(const std::vector<uint32_t>& candidates, double now, Try put, Badness badness, Restore restore) {
  int64_t best = -1;
  double best_bad = now;
  for (uint32_t e : candidates) {
    put(e);
    const double b = badness();
    if (b < best_bad) {
      best_bad = b;
      best = e;
    }
  }
  if (best < 0) {
    restore();
    return false;
  }
  put(uint32_t(best));
  return true;
}

uint32_t Encoder::encode_p2(const Query& q, Ctx& ctx, double cap) {
  const double bound = bound_for(threshold(thresholds_.p2, cap), q.values);
  const Match found = search_p2(q, bound, ctx);
  if (found.index >= 0) return uint32_t(found.index);
  const int na = grid_.n_alpha, nb = grid_.n_beta, n = na * nb;
  std::vector<float> recon(static_cast<size_t>(n));
  std::vector<uint32_t> idx(static_cast<size_t>(na));
  std::vector<float> sc(static_cast<size_t>(na));
  std::vector<uint8_t> exact(static_cast<size_t>(na), 0);
  const ChannelView& x = q.at(0, 0);
  auto place = [&](int a, const Match& r) {
    idx[size_t(a)] = uint32_t(r.index);
    sc[size_t(a)] = r.scale;
    const float* row = books_.p1.row(idx[size_t(a)]);
    for (int b = 0; b < nb; ++b) recon[size_t(a * nb + b)] = r.scale * row[b];
  };
  const double row_bound = bound_for(thresholds_.p1, size_t(nb));
  rows_ahead(
      na, ctx, [&] { return p1_store_.size(); },
      [&](int a, Ctx& c) { return search_p1(x.v + a * nb, q.unit, row_bound, c); },
      [&](int a, Match r) {
        if (r.index < 0) r = store_p1(x.v + a * nb, false);
        exact[size_t(a)] = r.score >= 1.0;
        place(a, r);
      });
  {
    const CauseScope<Cause> cause(cause_, kRetry);
    auto reuse = [&](int a, double now, const auto& badness) {
      const Match kept{int64_t(idx[size_t(a)]), 0.0, sc[size_t(a)]};
      float shape[256];
      unit_shape(x.v + a * nb, nb, shape);
      p1_index_.nearest(shape, kReuseCandidates, kProbes, ctx.order);
      const std::vector<uint32_t> candidates = ctx.order;
      return keep_best(
          candidates, now, [&](uint32_t e) { place(a, {int64_t(e), 0.0, p1_scale(x.v + a * nb, e)}); }, badness,
          [&] { place(a, kept); });
    };
    repair_parts(g2_, false, &x, 0, 1, q.unit, recon.data(), exact, bound, ctx, reuse,
                 [&](int a) { place(a, store_p1(x.v + a * nb, true)); });
  }
  const uint32_t e = insert_row(CodebookId::P2, p2_rows_, books_.p2_index, idx.data(), &books_.p2_scale, sc.data(), false);
  return e;
}

uint32_t Encoder::encode_i2(const Query& q, Ctx& ctx, double cap) {
  const double bound = bound_for(threshold(thresholds_.i2, cap), q.values);
  const Match found = search_i2(q, bound, ctx);
  if (found.index >= 0) return uint32_t(found.index);
  const int na = grid_.n_alpha, nb = grid_.n_beta, n = na * nb;
  std::vector<float> recon(static_cast<size_t>(2 * n)), row(static_cast<size_t>(2 * nb));
  std::vector<uint32_t> idx(static_cast<size_t>(na));
  std::vector<uint8_t> exact(static_cast<size_t>(na), 0);
  const ChannelView x[2] = {q.at(0, 1), q.at(0, 2)};
  auto place = [&](int a, uint32_t e) {
    idx[size_t(a)] = e;
    const float* y = i1_store_.values(e);
    std::copy(y, y + nb, recon.begin() + a * nb);
    std::copy(y + nb, y + 2 * nb, recon.begin() + n + a * nb);
  };
  // The row a as one (a, then b) vector, in `out` (2 nb floats).
  auto row_of = [&](int a, float* out) {
    std::copy(x[0].v + a * nb, x[0].v + (a + 1) * nb, out);
    std::copy(x[1].v + a * nb, x[1].v + (a + 1) * nb, out + nb);
  };
  auto encode_row = [&](int a, bool ex) {
    row_of(a, row.data());
    place(a, compose_i1(row.data(), q.unit, ctx, ex));
  };
  const double row_bound = bound_for(thresholds_.i1, size_t(2 * nb));
  rows_ahead(
      na, ctx, [&] { return i1_store_.size(); },
      [&](int a, Ctx& c) {
        thread_local std::vector<float> own;
        own.resize(size_t(2 * nb));
        row_of(a, own.data());
        return search_i1(own.data(), q.unit, row_bound, c);
      },
      [&](int a, const Match& r) {
        if (r.index >= 0) place(a, uint32_t(r.index));
        else encode_row(a, false);
      });
  {
    const CauseScope<Cause> cause(cause_, kRetry);
    auto reuse = [&](int a, double now, const auto& badness) {
      const uint32_t kept = idx[size_t(a)];
      row_of(a, row.data());
      i1_index_.nearest(row.data(), kReuseCandidates, kProbes, ctx.order);
      const std::vector<uint32_t> candidates = ctx.order;
      return keep_best(candidates, now, [&](uint32_t e) { place(a, e); }, badness, [&] { place(a, kept); });
    };
    repair_parts(g2_, false, x, 1, 2, q.unit, recon.data(), exact, bound, ctx, reuse, [&](int a) { encode_row(a, true); });
  }
  const uint32_t e = insert_row<uint32_t, uint32_t>(CodebookId::I2, i2_rows_, books_.i2, idx.data(), nullptr, nullptr, false);
  return e;
}

Encoder::Match Encoder::store_p1(const float* row, bool exact) {
  const int nb = grid_.n_beta;
  double sum = 0;
  for (int b = 0; b < nb; ++b) sum += row[b];
  std::vector<float> density(static_cast<size_t>(nb));
  for (int b = 0; b < nb; ++b) density[size_t(b)] = sum > 0 ? float(row[b] / sum) : 1.0f / float(nb);
  const uint32_t e = insert_row<float, float>(CodebookId::P1, p1_rows_, books_.p1, density.data(), nullptr, nullptr, exact);
  return {int64_t(e), 1.0, float(std::max(0.0, sum))};
}

uint32_t Encoder::compose_i1(const float* row, float unit, Ctx& ctx, bool exact) {
  const int nb = grid_.n_beta;
  const double bound = bound_for(thresholds_.i1, size_t(2 * nb));
  std::vector<float> recon(static_cast<size_t>(2 * nb));
  std::vector<uint32_t> idx(static_cast<size_t>(nb));
  std::vector<uint8_t> exact_c(static_cast<size_t>(nb), 0);
  auto place = [&](int b, bool ex) {
    idx[size_t(b)] = encode_c(row[b], row[nb + b], unit, ex);
    recon[size_t(b)] = books_.c.at(idx[size_t(b)], 0);
    recon[size_t(nb + b)] = books_.c.at(idx[size_t(b)], 1);
  };
  for (int b = 0; b < nb; ++b) place(b, exact);
  if (!exact) {
    std::vector<float> st(static_cast<size_t>(4 * nb));
    const ChannelView x[2] = {make_view(g1_, row, st.data(), st.data() + nb),
                              make_view(g1_, row + nb, st.data() + 2 * nb, st.data() + 3 * nb)};
    const CauseScope<Cause> cause(cause_, kRetry);
    auto no_reuse = [](int, double, const auto&) { return false; };
    repair_parts(g1_, true, x, 1, 2, unit, recon.data(), exact_c, bound, ctx, no_reuse, [&](int b) { place(b, true); });
  }
  const uint32_t e = insert_row<uint32_t, uint32_t>(CodebookId::I1, i1_rows_, books_.i1, idx.data(), nullptr, nullptr, exact);
  return e;
}

uint32_t Encoder::encode_c(float a, float b, float unit, bool exact) {
  // Plain Euclidean distance in absolute units (paper 4.4.1: a small constant threshold).
  const float ga = channel_scales(dyn_, 1) ? unit : 1.0f, gb = channel_scales(dyn_, 2) ? unit : 1.0f;
  const double limit = exact ? kExactC * kExactC : thresholds_.c * thresholds_.c;
  int64_t best = -1;
  double best_d = std::numeric_limits<double>::infinity();
  const float* c = books_.c.data().data();
  auto consider = [&](size_t e) {
    const double da = ga * (a - c[2 * e]), db = gb * (b - c[2 * e + 1]);
    const double d = da * da + db * db;
    if (d < best_d || (d == best_d && int64_t(e) < best)) {
      best_d = d;
      best = int64_t(e);
    }
  };
  // Only an entry within sqrt(limit) (absolute units) can be returned; in stored units that is a
  // box of half-width r per channel (with a margin for rounding). The grid visits the cells of that
  // box, unless they are many (dark slices: tiny unit), then the linear scan is cheaper.
  const double g = std::min(ga, gb);
  const double r = g > 0 ? std::sqrt(limit) / g * (1 + 1e-5) + 1e-6 : std::numeric_limits<double>::infinity();
  const size_t n = books_.c.rows();
  const double ncells = std::isfinite(r) ? (2 * r / kCCell + 2) * (2 * r / kCCell + 2) : 1e300;
  if (settings_.pruning && ncells <= 256 && ncells * 8 < double(n)) {
    for (int64_t i = c_cell(a - r), i1 = c_cell(a + r); i <= i1; ++i)
      for (int64_t j = c_cell(b - r), j1 = c_cell(b + r); j <= j1; ++j) {
        const auto it = c_grid_.find(c_key(i, j));
        if (it != c_grid_.end())
          for (uint32_t e : it->second) consider(e);
      }
  } else {
    for (size_t e = 0; e < n; ++e) consider(e);
  }
  if (best >= 0 && best_d <= limit) return uint32_t(best);
  const float v[2] = {a, b};
  const uint32_t e = insert_row<float, float>(CodebookId::C, c_rows_, books_.c, v, nullptr, nullptr, exact);
  return e;
}

void Encoder::check_frozen() const {
  if (books_.p4_index.rows() == 0) throw InputError("encoder: P4 is empty; grow the code-books before freezing them");
  if (p4_bright_.size() != books_.p4_index.rows() || p2_store_.size() != books_.p2_index.rows())
    throw InputError("encoder: the code-books grew outside this encoder; encode_growing() syncs them");
}

// The whole texel as a level-4 query (owning its window statistics) and its SSIM constants.
Encoder::Query Encoder::texel_query(const std::vector<float>& texel, Ctx& ctx, std::vector<float> stats) const {
  const size_t samples = grid_.samples();
  ctx.k = SsimConstants::make(settings_, dyn_, luminance_range(texel.data(), samples));
  ctx.scratch.resize(size_t(3 * g2_.size()));
  const int nplanes = grid_.n_phi_v * grid_.n_theta_v, n = g2_.size();
  Query q;
  q.planes = nplanes;
  q.values = size_t(3) * samples;
  q.stats = std::move(stats);
  q.stats.resize(size_t(2 * 3 * nplanes * n));
  q.views.resize(size_t(3 * nplanes));
  for_each_plane(nplanes, threads_, ctx.scratch, [&](int p, float*) {
    for (int c = 0; c < 3; ++c) {
      float* st = q.stats.data() + size_t(2 * (p * 3 + c) * n);
      q.views[size_t(p * 3 + c)] = make_view(g2_, texel.data() + size_t(c) * samples + size_t(p * n), st, st + n);
    }
  });
  q.order_planes(n);
  return q;
}

P6Entry Encoder::frozen_entry(const Query& q, const Match& best) const {
  P6Entry r;
  r.index = uint32_t(best.index);
  r.scale = best.scale;
  r.dissimilarity = score_to_dissimilarity(settings_.metric, best.score, q.values);
  return r;
}

P6Entry Encoder::encode_frozen(const float* texel_in) const {
  check_frozen();
  const std::vector<float> texel = clamped_texel(texel_in, grid_.samples(), dyn_);
  Ctx ctx;
  const Query q = texel_query(texel, ctx);
  return frozen_entry(q, search_composite(q, 4, kNoBound, ctx));
}

double Encoder::compose_frozen_p3(const Query& q, Ctx& ctx, uint32_t* m, float* scale) const {
  const int nt = grid_.n_theta_v;
  double bright = 0;
  prime_orders(q, 2, nt, 1, ctx);
  for (int t = 0; t < nt; ++t) {
    const Match best = search_composite(sub_query(q, t, 1), 2, kNoBound, ctx);
    if (best.index < 0) return -1;
    m[t] = uint32_t(best.index);
    scale[t] = best.scale;
    bright += best.scale * m_bright_[size_t(best.index)];
  }
  // Stored like a grown P3 entry: scales over the normalized brightness, which the P4 scale restores.
  const float norm = normalization(bright / nt);
  bright = 0;
  for (int t = 0; t < nt; ++t) {
    scale[t] /= norm;
    bright += scale[t] * m_bright_[m[t]];
  }
  return bright / nt;
}

bool Encoder::propose_p4(const float* texel_in, P4Proposal* out, bool compose_p3) const {
  check_frozen();
  const std::vector<float> texel = clamped_texel(texel_in, grid_.samples(), dyn_);
  Ctx ctx;
  const Query q = texel_query(texel, ctx);
  const int n = g2_.size(), nt = grid_.n_theta_v, np = grid_.n_phi_v;
  out->p3.assign(size_t(np), 0);
  out->scale.assign(size_t(np), 0.0f);
  out->new_m.clear();
  out->new_scale.clear();
  // The planes of group p at factor (a new P3 row's from the proposal itself).
  auto group_planes = [&](int p, float factor, std::vector<PlaneRef>& planes) {
    if (!out->is_new(size_t(p))) return p3_planes(out->p3[size_t(p)], factor, planes);
    const size_t row = size_t(out->p3[size_t(p)] - P4Proposal::kNewP3) * size_t(nt);
    m_planes(out->new_m.data() + row, out->new_scale.data() + row, factor, planes);
  };
  double bright = 0;
  std::vector<uint32_t> m(static_cast<size_t>(nt));
  std::vector<float> ms(static_cast<size_t>(nt));
  std::vector<PlaneRef> planes;
  prime_orders(q, 3, np, nt, ctx);
  for (int p = 0; p < np; ++p) {
    Query sub = sub_query(q, p * nt, nt);
    sub.order_planes(n);
    const Match best = search_composite(sub, 3, kNoBound, ctx);
    if (best.index < 0) return false;
    out->p3[size_t(p)] = uint32_t(best.index);
    out->scale[size_t(p)] = best.scale;
    double group_bright = p3_bright_[size_t(best.index)];
    if (compose_p3 && best.score < bound_for(thresholds_.p3, sub.values)) {
      const double b = compose_frozen_p3(sub, ctx, m.data(), ms.data());
      planes.clear();
      m_planes(m.data(), ms.data(), 1.0f, planes);
      double score;
      float s = 1;
      if (b >= 0 && evaluate_composite(sub, planes.data(), nt, kNoBound, ctx, &score, &s) && score > best.score) {
        out->p3[size_t(p)] = P4Proposal::kNewP3 + uint32_t(out->new_m.size() / size_t(nt));
        out->scale[size_t(p)] = s;
        out->new_m.insert(out->new_m.end(), m.begin(), m.end());
        out->new_scale.insert(out->new_scale.end(), ms.begin(), ms.end());
        group_bright = b;
      }
    }
    bright += out->scale[size_t(p)] * group_bright;
  }
  // Stored like a grown P4 entry: normalized scales, the brightness in the texel's P6 scale.
  const float norm = normalization(bright / np);
  planes.clear();
  for (int p = 0; p < np; ++p) {
    out->scale[size_t(p)] /= norm;
    group_planes(p, out->scale[size_t(p)], planes);
  }
  double score;
  float s = 1;
  evaluate_composite(q, planes.data(), int(planes.size()), kNoBound, ctx, &score, &s);
  out->entry.index = 0;
  out->entry.scale = s;
  out->entry.dissimilarity = score_to_dissimilarity(settings_.metric, score, q.values);
  return true;
}

P6Entry Encoder::adopt_p4(const P4Proposal& proposal) {
  std::vector<uint32_t> p3 = proposal.p3;
  const size_t nt = size_t(grid_.n_theta_v);
  for (size_t p = 0; p < p3.size(); ++p)
    if (proposal.is_new(p)) {
      const size_t row = size_t(p3[p] - P4Proposal::kNewP3) * nt;
      p3[p] = insert_row(CodebookId::P3, p3_rows_, books_.p3_index, proposal.new_m.data() + row, &books_.p3_scale,
                         proposal.new_scale.data() + row, false);
    }
  P6Entry r = proposal.entry;
  r.index = store_p4(p3.data(), proposal.scale.data());
  return r;
}

P6Entry Encoder::encode_frozen_among(const float* texel_in, const std::vector<uint32_t>& order, double floor) const {
  check_frozen();
  const std::vector<float> texel = clamped_texel(texel_in, grid_.samples(), dyn_);
  Ctx ctx;
  const Query q = texel_query(texel, ctx);
  const Match best = search_composite_in(q, 4, order, floor, ctx);
  if (best.index < 0) throw InputError("encoder: no candidate reaches the given floor score");
  return frozen_entry(q, best);
}

P6Entry Encoder::encode_frozen_among(const FrozenQuery& f, const std::vector<uint32_t>& order, double floor) const {
  check_frozen();
  Ctx ctx;
  const Query q = frozen_texel_query(f, ctx);
  const Match best = search_composite_in(q, 4, order, floor, ctx);
  if (best.index < 0) throw InputError("encoder: no candidate reaches the given floor score");
  return frozen_entry(q, best);
}

FrozenQuery Encoder::frozen_query(const float* texel_in) const {
  FrozenQuery f;
  frozen_query(texel_in, f);
  return f;
}

void Encoder::frozen_query(const float* texel_in, FrozenQuery& f) const {
  check_frozen();
  clamp_texel(texel_in, grid_.samples(), dyn_, f.texel);
  Ctx ctx;
  Query q = texel_query(f.texel, ctx, std::move(f.stats));
  order_composite(q, 4, ctx);
  for (int c = 0; c < 3; ++c) {
    f.c1[c] = ctx.k.c1[c];
    f.c2[c] = ctx.k.c2[c];
  }
  f.stats = std::move(q.stats);
  f.candidates = std::move(ctx.order);
}

// The texel query of a FrozenQuery, borrowing its values and window statistics.
Encoder::Query Encoder::frozen_texel_query(const FrozenQuery& f, Ctx& ctx) const {
  const size_t samples = grid_.samples();
  for (int c = 0; c < 3; ++c) {
    ctx.k.c1[c] = f.c1[c];
    ctx.k.c2[c] = f.c2[c];
  }
  ctx.scratch.resize(size_t(3 * g2_.size()));
  const int nplanes = grid_.n_phi_v * grid_.n_theta_v, n = g2_.size();
  if (f.texel.size() != 3 * samples || f.stats.size() != size_t(2 * 3 * nplanes * n))
    throw InputError("encoder: a frozen query of another grid");
  Query q;
  q.planes = nplanes;
  q.values = size_t(3) * samples;
  for (int p = 0; p < nplanes; ++p)
    for (int c = 0; c < 3; ++c) {
      const float* st = f.stats.data() + size_t(2 * (p * 3 + c) * n);
      q.views.push_back(view_of(g2_, f.texel.data() + size_t(c) * samples + size_t(p * n), st, st + n));
    }
  q.order_planes(n);
  return q;
}

void Encoder::p4_planes(uint32_t e, std::vector<uint32_t>& p2, std::vector<uint32_t>& i2,
                        std::vector<float>& factor) const {
  std::vector<PlaneRef> planes;
  planes_of_p4(e, planes);
  for (const PlaneRef& r : planes) {
    p2.push_back(r.p2);
    i2.push_back(r.i2);
    factor.push_back(r.factor);
  }
}

double Encoder::texel_dissimilarity(const float* texel, uint32_t p4, float scale) const {
  std::vector<float> recon(size_t(3) * grid_.samples());
  reconstruct_texel(books_, dyn_, p4, scale, recon.data());
  return btfvq::texel_dissimilarity(settings_, dyn_, grid_, texel, recon.data());
}

void reconstruct_texel(const Codebooks& k, Dynamic dyn, uint32_t p4, float scale, float* out) {
  const AngularGrid& g = k.grid;
  const size_t samples = g.samples();
  if (p4 >= k.p4_index.rows()) throw InputError("reconstruct_texel: P4 index " + std::to_string(p4) + " is past the end of P4");
  for (int p = 0; p < g.n_phi_v; ++p) {
    const uint32_t p3 = k.p4_index.at(p4, size_t(p));
    const float s4 = k.p4_scale.at(p4, size_t(p));
    for (int t = 0; t < g.n_theta_v; ++t) {
      const uint32_t m = k.p3_index.at(p3, size_t(t));
      const float s = scale * s4 * k.p3_scale.at(p3, size_t(t));
      const uint32_t p2 = k.m.at(m, 0), i2 = k.m.at(m, 1);
      for (int a = 0; a < g.n_alpha; ++a) {
        const float* density = k.p1.row(k.p2_index.at(p2, size_t(a)));
        const float ps = k.p2_scale.at(p2, size_t(a));
        const uint32_t* colours = k.i1.row(k.i2.at(i2, size_t(a)));
        for (int b = 0; b < g.n_beta; ++b) {
          const size_t i = g.index(p, t, a, b);
          const float lab[3] = {ps * density[b], k.c.at(colours[b], 0), k.c.at(colours[b], 1)};
          for (int c = 0; c < 3; ++c) {
            const float o = channel_offset(dyn, c);
            out[size_t(c) * samples + i] = channel_scales(dyn, c) ? o + s * (lab[c] - o) : lab[c];
          }
        }
      }
    }
  }
}

double texel_dissimilarity(const SimilaritySettings& s, Dynamic dyn, const AngularGrid& grid, const float* texel,
                           const float* reconstruction) {
  const WindowGeometry g(grid.n_alpha, grid.n_beta, s.window_radius);
  const size_t samples = grid.samples();
  const float range = luminance_range(texel, samples);
  const double sim = slice_similarity(s, dyn, g, texel, reconstruction, grid.n_phi_v * grid.n_theta_v, 0, 3, range);
  return s.metric == Metric::SSIM ? 1.0 - sim : -sim;
}

}  // namespace btfvq
