#include "pipeline/encode/frozen_search.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include <btfvq/error.h>
#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/util/parallel.h"

namespace btfvq {

namespace {

// Half-width of the rounding margin around a bin's edges: the kernel, its reference and the exact
// comparison sum the same float products in different orders (differences are ~1e-5 in SSIM).
constexpr double kMargin = 5e-4;
// BatchedMSE's rounding margin: the numerators are float sums (16 lanes, then double per plane) of values
// in 8-bit units, ~1e-6 relative to <x, x> + s^2 <y, y> (Cauchy-Schwarz bounds 2 s <x, y> by it);
// the exact search adds float differences. 1e-4 of it is two orders above both and still settles
// about one candidate per texel (docs/similarity.md "Under MSE: the closed form").
constexpr double kRelativeMargin = 1e-4;
// kernels/search.cl's histogram and its private row buffer.
constexpr int kBins = 512, kMaxRows = 30, kLanes = 16, kMaxPlanes = 256;
// Launches of at most kChunk texels bound the padded queries and the scratch values (~1 MB per texel).
constexpr size_t kChunk = 128;

double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

// The padded row layout of kernels/search.cl: one plane channel as (rows + 2 radius) rows of 16
// lanes of values with a zero border, then rows x 16 window means and rows x 16 variances.
struct PaddedPlane {
  int rows, cols, radius;
  static bool fits(int rows, int cols, int radius) {
    return radius <= 2 && cols + 2 * radius <= kLanes && rows <= kMaxRows;
  }
  size_t padded() const { return size_t(rows + 2 * radius); }
  size_t block() const { return (padded() + 2 * size_t(rows)) * kLanes; }
  // Values and means minus the channel offset (kernels/search.cl). Every float of the block is
  // written once, row by row: a batch packs ~750 KB per texel.
  void pack(const float* v, const float* mean, const float* var, float offset, float* out) const {
    auto row = [&](float* at, const float* from, float minus) {
      std::fill(at, at + radius, 0.0f);
      for (int c = 0; c < cols; ++c) at[radius + c] = from[c] - minus;
      std::fill(at + radius + cols, at + kLanes, 0.0f);
    };
    std::fill(out, out + size_t(radius) * kLanes, 0.0f);
    float* m = out + padded() * kLanes;
    std::fill(m - size_t(radius) * kLanes, m, 0.0f);
    float* w = m + size_t(rows) * kLanes;
    for (int r = 0; r < rows; ++r) {
      const size_t i = size_t(r * cols), at = size_t(r) * kLanes;
      row(out + size_t(radius) * kLanes + at, v + i, offset);
      row(m + at, mean + i, offset);
      row(w + at, var + i, 0.0f);
    }
  }
};

// The C++ reference of kernels/search.cl's search_texels for one texel, scalar and on the unpadded
// layout (FrozenSearch::query_block; SliceStore blocks): the same order, scale, abandonment and bins.
struct ReferenceInputs {
  const uint32_t *plane_p2, *plane_i2;
  const float *plane_f, *entry_yy, *lum, *chroma, *inv_count;
  size_t lum_stride, chroma_stride;
  int rows, cols, radius, planes, hdr, keep;
};

float search_offset(int hdr, int c) { return hdr ? 0.0f : (c == 0 ? 16.0f : 128.0f); }
bool search_scales(int hdr, int c) { return !hdr || c == 0; }

void search_reference(const ReferenceInputs& in, const float* query, const float* consts, const uint32_t* candidates,
                      const float* nums, size_t slots, int* bins) {
  const int n = in.rows * in.cols;
  // Where the candidate's values, means and variances of plane channel c live, and their spacing.
  auto entry = [&](size_t e, int j, int c, int* spacing) {
    const size_t at = e * size_t(in.planes) + size_t(j);
    *spacing = c == 0 ? n : 2 * n;
    return c == 0 ? in.lum + in.plane_p2[at] * in.lum_stride
                  : in.chroma + in.plane_i2[at] * in.chroma_stride + size_t(c - 1) * size_t(n);
  };
  std::vector<float> values(size_t(in.planes) * 3 * size_t(n));
  float floor = -1e30f;
  std::vector<int> order(size_t(in.planes));
  for (int j = 0; j < in.planes; ++j) order[size_t(j)] = j;
  for (size_t k = 0; k < slots; ++k) {
    const size_t e = candidates[k];
    const float num = nums[k], den = in.entry_yy[e];
    const float s = den > 1e-20f ? std::max(num / den, 0.0f) : 1.0f;
    int below = 0;
    for (int q = 0; q < in.planes && below < in.keep; ++q)
      for (int c = 0, j = order[size_t(q)]; c < 3; ++c) {
        int spacing;
        const float* x = query + size_t(j * 3 + c) * 3 * size_t(n);
        const float* y = entry(e, j, c, &spacing);
        const bool scaled = search_scales(in.hdr, c);
        const float b = scaled ? s * in.plane_f[e * size_t(in.planes) + size_t(j)] : 1.0f;
        const float a = scaled ? search_offset(in.hdr, c) * (1.0f - b) : 0.0f;
        const float c1 = consts[c], c2 = consts[3 + c];
        for (int r = 0; r < in.rows; ++r)
          for (int col = 0; col < in.cols; ++col) {
            float exy = 0.0f;
            for (int rr = std::max(r - in.radius, 0); rr <= std::min(r + in.radius, in.rows - 1); ++rr)
              for (int kk = std::max(col - in.radius, 0); kk <= std::min(col + in.radius, in.cols - 1); ++kk)
                exy += x[rr * in.cols + kk] * y[rr * in.cols + kk];
            const int i = r * in.cols + col;
            const float mx = x[n + i], ym = y[spacing + i], my = a + b * ym;
            const float cov = b * (exy * in.inv_count[i] - mx * ym);
            const float vx = x[2 * n + i], vy = b * b * y[2 * spacing + i];
            const float v = ((2.0f * mx * my + c1) * (2.0f * cov + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2));
            values[size_t(j * 3 + c) * size_t(n) + size_t(i)] = v;
            below += v < floor;
          }
      }
    if (below >= in.keep) {
      bins[k] = -1;
      continue;
    }
    std::vector<unsigned> histogram(kBins, 0);
    for (float v : values) histogram[size_t(std::clamp(int(v * float(kBins)), 0, kBins - 1))] += 1;
    int bin = kBins - 1;
    for (unsigned seen = 0, b = 0; b < unsigned(kBins); ++b)
      if ((seen += histogram[b]) >= unsigned(in.keep)) {
        bin = int(b);
        break;
      }
    bins[k] = bin;
    if (k == 0) {
      // The planes holding most of the first candidate's values in bins 0..bin first (stable).
      std::vector<int> low(size_t(in.planes), 0);
      for (size_t i = 0; i < values.size(); ++i)
        low[i / (3 * size_t(n))] += std::clamp(int(values[i] * float(kBins)), 0, kBins - 1) <= bin;
      std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return low[size_t(a)] > low[size_t(b)]; });
    }
    floor = std::max(floor, bin <= 0 ? -1e30f : float(bin) / float(kBins) - float(kMargin));
  }
}

// The bracket of a candidate the batch abandoned: below every completed one's.
constexpr double kAbandoned = -std::numeric_limits<double>::infinity();

// A texel's search settled exactly, as both batched paths end: of its candidates (slots, with score
// brackets [lower, upper]) only those whose bracket reaches the best lower bound can win; the pruned
// search runs among them, likeliest first, with that bound as its floor, so it picks what it would
// have picked among all of them.
P6Entry settle(const Encoder& encoder, const FrozenQuery& q, const uint32_t* candidates, const double* lower,
               const double* upper, size_t slots, size_t* settled) {
  const double floor = *std::max_element(lower, lower + slots);
  std::vector<size_t> keep;
  for (size_t k = 0; k < slots; ++k)
    if (upper[k] > kAbandoned && upper[k] >= floor) keep.push_back(k);
  std::stable_sort(keep.begin(), keep.end(), [&](size_t a, size_t b) { return lower[a] > lower[b]; });
  std::vector<uint32_t> pick;
  for (size_t k : keep) pick.push_back(candidates[k]);
  *settled = pick.size();
  return encoder.encode_frozen_among(q, pick, floor);
}

}  // namespace

struct FrozenSearch::Device {
  cl::Buffer plane_p2, plane_i2, plane_f, entry_yy, lum, chroma, inv_count;
  // Per-launch buffers, kept for the next batch: padded queries, constants, candidates, scratch, bins.
  cl::Buffer queries, consts, candidates, nums, scratch, bins;
  size_t slots = 0;  // capacity of candidates, nums and bins: kChunk x slots
};

bool FrozenSearch::kernel_fits(const AngularGrid& g, int radius) {
  return PaddedPlane::fits(g.n_alpha, g.n_beta, radius) && g.n_phi_v * g.n_theta_v <= kMaxPlanes;
}

SearchPath FrozenSearch::preferred(const AngularGrid& g, const SimilaritySettings& s) {
  // Measured in BENCHMARKS.md "Phase 3 search paths": the vectorized kernel on PoCL is faster than
  // the pruned search on the CPU; without OpenCL (or for planes the kernel's rows cannot hold) the
  // pruned search is the fastest path.
  // Under MSE the closed form needs no device and is faster than either.
  if (s.metric == Metric::MSE) return SearchPath::BatchedMSE;
  if (kernel_fits(g, s.window_radius) && ComputeDevice::get().uses_opencl()) return SearchPath::BatchedOpenCL;
  return SearchPath::Pruned;
}

FrozenSearch::FrozenSearch(const Encoder& encoder, SearchPath path, int threads)
    : encoder_(encoder), path_(path), threads_(std::max(1, threads)) {
  // The histogram brackets SSIM percentiles: under MSE the batch is the closed form, which holds
  // the scaled channels only (HDR chroma is compared unscaled: the pruned search).
  const bool mse = encoder.settings().metric == Metric::MSE;
  if (!mse && path_ == SearchPath::BatchedMSE) throw InputError("frozen search: the MSE batch under the SSIM metric");
  if (mse && path_ != SearchPath::Pruned)
    path_ = encoder.dynamic() == Dynamic::HDR ? SearchPath::Pruned : SearchPath::BatchedMSE;
  if (path_ == SearchPath::Pruned) return;
  const Codebooks& k = encoder.codebooks();
  const AngularGrid& g = k.grid;
  const int radius = encoder.settings().window_radius;
  const WindowGeometry geometry(g.n_alpha, g.n_beta, radius);
  for (int i = 0; i < geometry.size(); ++i) inv_count_.push_back(geometry.inv_count(i));
  keep_ = int(std::floor(encoder.settings().outlier_fraction * double(3 * g.samples()) + 1e-9)) + 1;
  const size_t n = size_t(geometry.size());
  const int hdr = encoder.dynamic() == Dynamic::HDR;
  // Each code-book entry channel's sum of squares about the offset: the least-squares denominators.
  auto squares = [&](const SliceStore& store, int first, std::vector<double>& yy) {
    const size_t channels = size_t(store.channels());
    yy.assign(store.size() * channels, 0.0);
    for (size_t e = 0; e < store.size(); ++e)
      for (size_t c = 0; c < channels; ++c) {
        const float* v = store.blocks().data() + e * store.stride() + c * n;
        const float o = search_offset(hdr, first + int(c));
        for (size_t i = 0; i < n; ++i) yy[e * channels + c] += double(v[i] - o) * double(v[i] - o);
      }
  };
  squares(encoder.luminance_planes(), 0, lum_yy_);
  squares(encoder.chroma_planes(), 1, chroma_yy_);
  if (path_ != SearchPath::BatchedOpenCL) {
    sync();
    return;
  }
  auto& dev = ComputeDevice::get();
  if (!dev.uses_opencl()) throw DeviceError("the batched OpenCL search needs OpenCL: " + dev.description());
  if (!kernel_fits(g, radius))
    throw DeviceError("the batched OpenCL search holds at most " + std::to_string(kMaxPlanes) + " planes of at most " +
                      std::to_string(kMaxRows) + " x " + std::to_string(kLanes - 2 * radius) +
                      " samples at window radius " + std::to_string(radius) + " (at most 2); this grid has " +
                      std::to_string(g.n_phi_v * g.n_theta_v) + " planes of " + std::to_string(g.n_alpha) + " x " +
                      std::to_string(g.n_beta));
  const PaddedPlane layout{g.n_alpha, g.n_beta, radius};
  // Code-book planes in the kernel's padded rows (one block per channel; channel c of the store is
  // colour channel first + c).
  auto padded = [&](const SliceStore& store, int first) {
    const size_t channels = size_t(store.channels()), entries = store.size();
    std::vector<float> out(entries * channels * layout.block());
    for (size_t e = 0; e < entries; ++e)
      for (size_t c = 0; c < channels; ++c) {
        const float* v = store.blocks().data() + e * store.stride() + c * n;
        layout.pack(v, v + channels * n, v + 2 * channels * n, search_offset(hdr, first + int(c)),
                    out.data() + (e * channels + c) * layout.block());
      }
    return out;
  };
  const std::vector<float> lum = padded(encoder.luminance_planes(), 0);
  const std::vector<float> chroma = padded(encoder.chroma_planes(), 1);
  std::vector<float> inv(size_t(g.n_alpha) * kLanes, 0.0f);
  for (int r = 0; r < g.n_alpha; ++r)
    for (int c = 0; c < g.n_beta; ++c) inv[size_t(r) * kLanes + size_t(c + radius)] = inv_count_[size_t(r * g.n_beta + c)];
  device_ = std::make_unique<Device>();
  opencl_call("uploading the frozen code-books", [&] {
    device_->lum = dev.upload(lum);
    device_->chroma = dev.upload(chroma);
    device_->inv_count = dev.upload(inv);
  });
  sync();
}

FrozenSearch::~FrozenSearch() = default;

void FrozenSearch::sync() {
  const Codebooks& k = encoder_.codebooks();
  if (path_ == SearchPath::Pruned || entries_ == k.p4_index.rows()) return;
  const AngularGrid& g = k.grid;
  const int hdr = encoder_.dynamic() == Dynamic::HDR;
  // The planes of the entries added since, and their least-squares denominators: the sum over
  // planes and scaled channels of f^2 yy.
  const size_t planes = size_t(g.n_phi_v * g.n_theta_v);
  for (uint32_t e = uint32_t(entries_); e < k.p4_index.rows(); ++e) {
    encoder_.p4_planes(e, plane_p2_, plane_i2_, plane_f_);
    double d = 0;
    for (size_t j = 0; j < planes; ++j) {
      const size_t at = size_t(e) * planes + j;
      double yy = lum_yy_[plane_p2_[at]];
      if (search_scales(hdr, 1)) yy += chroma_yy_[plane_i2_[at] * 2] + chroma_yy_[plane_i2_[at] * 2 + 1];
      d += double(plane_f_[at]) * double(plane_f_[at]) * yy;
    }
    entry_yy_.push_back(float(d));
  }
  entries_ = k.p4_index.rows();
  if (!device_) return;
  auto& dev = ComputeDevice::get();
  opencl_call("uploading the P4 entries", [&] {
    device_->plane_p2 = dev.upload(plane_p2_);
    device_->plane_i2 = dev.upload(plane_i2_);
    device_->plane_f = dev.upload(plane_f_);
    device_->entry_yy = dev.upload(entry_yy_);
  });
}

void FrozenSearch::bracket(int bin, double* lower, double* upper) {
  *lower = bin <= 0 ? -1e300 : double(bin) / kBins - kMargin;
  *upper = bin >= kBins - 1 ? 1e300 : double(bin + 1) / kBins + kMargin;
}

// Phase 3 keeps its configured worker count (schedule.threads).
template <class F>
void FrozenSearch::parallel(size_t n, F&& f) const {
  parallel_for(0, n, f, {.threads = size_t(threads_)});
}

std::vector<float> FrozenSearch::query_block(const FrozenQuery& q) const {
  const AngularGrid& g = encoder_.codebooks().grid;
  const size_t n = size_t(g.n_alpha * g.n_beta), planes = size_t(g.n_phi_v * g.n_theta_v), samples = g.samples();
  std::vector<float> block(planes * 3 * 3 * n);
  for (size_t p = 0; p < planes; ++p)
    for (size_t c = 0; c < 3; ++c) {
      float* out = block.data() + (p * 3 + c) * 3 * n;
      const float* v = q.texel.data() + c * samples + p * n;
      const float* st = q.stats.data() + (p * 3 + c) * 2 * n;
      std::copy(v, v + n, out);
      std::copy(st, st + 2 * n, out + n);
    }
  return block;
}

void FrozenSearch::check_batch(const std::vector<FrozenQuery>& queries, const std::vector<uint32_t>& candidates,
                               size_t slots) const {
  if (candidates.size() != queries.size() * slots) throw InputError("frozen search: candidates must be texels x slots");
  for (uint32_t e : candidates)
    if (e >= entries_) throw InputError("frozen search: candidate past the end of P4");
  const AngularGrid& g = encoder_.codebooks().grid;
  for (const FrozenQuery& q : queries)
    if (q.texel.size() != 3 * g.samples() || q.stats.size() != 2 * 3 * g.samples())
      throw InputError("frozen search: a query of another grid (use Encoder::frozen_query)");
}

void FrozenSearch::squared_errors(const std::vector<FrozenQuery>& queries, const std::vector<uint32_t>& candidates,
                                  size_t slots, std::vector<double>* error, std::vector<double>* margin) const {
  if (path_ != SearchPath::BatchedMSE) throw InputError("frozen search: squared errors are the MSE batch's");
  check_batch(queries, candidates, slots);
  const std::vector<float> nums = scale_numerators(queries, candidates, slots);
  const size_t samples = encoder_.codebooks().grid.samples();
  error->resize(candidates.size());
  margin->resize(candidates.size());
  parallel(queries.size(), [&](size_t t) {
    // <x, x> over the scaled channels (all three in LDR), offsets removed.
    double xx = 0;
    for (int c = 0; c < 3; ++c) {
      const float* v = queries[t].texel.data() + size_t(c) * samples;
      const double o = search_offset(0, c);
      for (size_t i = 0; i < samples; ++i) xx += (double(v[i]) - o) * (double(v[i]) - o);
    }
    for (size_t k = t * slots; k < (t + 1) * slots; ++k) {
      const double num = nums[k], den = entry_yy_[candidates[k]];
      const double s = den > 1e-20 ? std::max(0.0, num / den) : 1.0;
      (*error)[k] = std::max(0.0, xx - 2 * s * num + s * s * den);
      (*margin)[k] = kRelativeMargin * (xx + s * s * den) + 1e-9;
    }
  });
}

std::vector<int> FrozenSearch::bins(const std::vector<FrozenQuery>& queries, const std::vector<uint32_t>& candidates,
                                    size_t slots) {
  if (path_ != SearchPath::BatchedOpenCL && path_ != SearchPath::BatchedReference)
    throw InputError("frozen search: only the SSIM batch has bins");
  check_batch(queries, candidates, slots);
  const size_t texels = queries.size();
  std::vector<int> out(texels * slots);
  if (out.empty()) return out;
  const auto t0 = std::chrono::steady_clock::now();
  const std::vector<float> nums = scale_numerators(queries, candidates, slots);
  if (path_ == SearchPath::BatchedReference) bins_reference(queries, candidates, slots, nums, out);
  else bins_opencl(queries, candidates, slots, nums, out);
  stats_.device_seconds += seconds_since(t0);
  return out;
}

// Per (texel, slot), the least-squares scale's numerator: the sum over planes j and scaled channels of
// f_j <x_j - o, y_j - o>. Every candidate needs all planes (most are then abandoned after a few), so
// per candidate this reads the entry's whole reconstruction, scattered over the P2 and I2 stores: in
// the kernel, from memory, two thirds of its time (proposte 256). A batch's texels share most of
// their candidates (256 texels x 32 slots name ~800 entries there), so here the pairs are grouped by
// entry and walked plane by plane: an entry's plane is read once per batch and the texels' planes
// stay in cache.
std::vector<float> FrozenSearch::scale_numerators(const std::vector<FrozenQuery>& queries,
                                                  const std::vector<uint32_t>& candidates, size_t slots) const {
  const AngularGrid& g = encoder_.codebooks().grid;
  const size_t n = size_t(g.n_alpha * g.n_beta), planes = size_t(g.n_phi_v * g.n_theta_v), samples = g.samples();
  const int hdr = encoder_.dynamic() == Dynamic::HDR;
  const SliceStore &lum = encoder_.luminance_planes(), &chroma = encoder_.chroma_planes();
  const size_t texels = queries.size(), pairs = candidates.size();
  // The pairs in entry order, and where each entry's pairs begin (then the end). A part takes the
  // entries that begin in its share of the pairs, so that no two threads add to one sum.
  std::vector<uint32_t> by_entry(pairs);
  for (size_t i = 0; i < pairs; ++i) by_entry[i] = uint32_t(i);
  std::stable_sort(by_entry.begin(), by_entry.end(),
                   [&](uint32_t a, uint32_t b) { return candidates[a] < candidates[b]; });
  std::vector<size_t> groups;
  for (size_t i = 0; i < pairs; ++i)
    if (i == 0 || candidates[by_entry[i]] != candidates[by_entry[i - 1]]) groups.push_back(i);
  groups.push_back(pairs);
  const size_t parts = std::min(pairs, size_t(threads_));
  auto first_group = [&](size_t part) {
    return size_t(std::lower_bound(groups.begin(), groups.end(), pairs * part / parts) - groups.begin());
  };
  std::vector<double> sums(pairs, 0.0);  // in by_entry's order: each thread adds to its own range
  // A texel's plane as lum (n) and chroma a, b (2n) values, each part padded with zeros to whole
  // kLanes where the entry's block goes on that far: the sums then read past an entry's values into
  // its window means (finite), which add zero, and need no scalar tail.
  auto span_of = [](size_t m, size_t stride) {
    const size_t whole = (m + kLanes - 1) / kLanes * kLanes;
    return whole <= stride ? whole : m;
  };
  const size_t lum_span = span_of(n, lum.stride()), chroma_span = span_of(2 * n, chroma.stride());
  const size_t span = lum_span + chroma_span;
  // Adds x (y - o) over m values to kLanes partial sums (the loop vectorizes without reassociation).
  auto add = [](float* lane, const float* x, const float* y, float o, size_t m) {
    size_t i = 0;
    for (; i + kLanes <= m; i += kLanes)
      for (size_t l = 0; l < size_t(kLanes); ++l) lane[l] += x[i + l] * (y[i + l] - o);
    for (size_t l = 0; i < m; ++i, ++l) lane[l] += x[i] * (y[i] - o);
  };
  auto total = [](float* lane) {
    for (size_t w = kLanes / 2; w > 0; w /= 2)
      for (size_t l = 0; l < w; ++l) lane[l] += lane[l + w];
    return lane[0];
  };
  parallel(parts, [&](size_t part) {
    const size_t g0 = first_group(part), g1 = first_group(part + 1);
    std::vector<float> x(texels * span, 0.0f);  // plane j of every texel, offset removed
    for (size_t j = 0; j < planes; ++j) {
      for (size_t t = 0; t < texels; ++t)
        for (size_t c = 0; c < 3; ++c) {
          const float* v = queries[t].texel.data() + c * samples + j * n;
          const float o = search_offset(hdr, int(c));
          float* out = x.data() + t * span + (c == 0 ? 0 : lum_span + (c - 1) * n);
          for (size_t i = 0; i < n; ++i) out[i] = v[i] - o;
        }
      auto planes_of = [&](size_t group, const float** y, const float** ab) {
        const size_t at = size_t(candidates[by_entry[groups[group]]]) * planes + j;
        *y = lum.blocks().data() + plane_p2_[at] * lum.stride();
        *ab = chroma.blocks().data() + plane_i2_[at] * chroma.stride();
        return at;
      };
      for (size_t group = g0; group < g1; ++group) {
        // The entries' planes are scattered over the stores: fetch the next entry's while this one's
        // pairs are summed.
        if (group + 1 < g1) {
          const float *y, *ab;
          planes_of(group + 1, &y, &ab);
          for (size_t b = 0; b < n * sizeof(float); b += 64) __builtin_prefetch(reinterpret_cast<const char*>(y) + b);
          for (size_t b = 0; b < 2 * n * sizeof(float); b += 64) __builtin_prefetch(reinterpret_cast<const char*>(ab) + b);
        }
        const float *y, *ab;
        const double f = plane_f_[planes_of(group, &y, &ab)];
        for (size_t i = groups[group]; i < groups[group + 1]; ++i) {
          const float* xt = x.data() + size_t(by_entry[i] / slots) * span;
          float lane[kLanes] = {};
          add(lane, xt, y, search_offset(hdr, 0), lum_span);
          // Both chroma channels at once: they lie one after the other in the query and the entry.
          if (search_scales(hdr, 1)) add(lane, xt + lum_span, ab, search_offset(hdr, 1), chroma_span);
          sums[i] += f * double(total(lane));
        }
      }
    }
  });
  std::vector<float> out(pairs);
  for (size_t i = 0; i < pairs; ++i) out[by_entry[i]] = float(sums[i]);
  return out;
}

void FrozenSearch::bins_reference(const std::vector<FrozenQuery>& queries, const std::vector<uint32_t>& candidates,
                                  size_t slots, const std::vector<float>& nums, std::vector<int>& out) const {
  const AngularGrid& g = encoder_.codebooks().grid;
  const ReferenceInputs in{plane_p2_.data(),
                           plane_i2_.data(),
                           plane_f_.data(),
                           entry_yy_.data(),
                           encoder_.luminance_planes().blocks().data(),
                           encoder_.chroma_planes().blocks().data(),
                           inv_count_.data(),
                           encoder_.luminance_planes().stride(),
                           encoder_.chroma_planes().stride(),
                           g.n_alpha,
                           g.n_beta,
                           encoder_.settings().window_radius,
                           g.n_phi_v * g.n_theta_v,
                           encoder_.dynamic() == Dynamic::HDR,
                           keep_};
  parallel(queries.size(), [&](size_t t) {
    const std::vector<float> block = query_block(queries[t]);
    float consts[6];
    for (int c = 0; c < 3; ++c) consts[c] = queries[t].c1[c], consts[3 + c] = queries[t].c2[c];
    search_reference(in, block.data(), consts, candidates.data() + t * slots, nums.data() + t * slots, slots,
                     out.data() + t * slots);
  });
}

void FrozenSearch::bins_opencl(const std::vector<FrozenQuery>& queries, const std::vector<uint32_t>& candidates,
                               size_t slots, const std::vector<float>& nums, std::vector<int>& out) const {
  const AngularGrid& g = encoder_.codebooks().grid;
  const int rows = g.n_alpha, cols = g.n_beta, planes = g.n_phi_v * g.n_theta_v;
  const int radius = encoder_.settings().window_radius, hdr = encoder_.dynamic() == Dynamic::HDR;
  const PaddedPlane layout{rows, cols, radius};
  const size_t n = size_t(rows * cols), samples = g.samples(), stride = size_t(planes) * 3 * layout.block();
  auto& dev = ComputeDevice::get();
  cl::CommandQueue& queue = dev.queue();
  Device& d = *device_;
  const size_t scratch = size_t(planes) * 3 * size_t(rows) * 2 * kLanes;
  opencl_call("allocating the batch buffers", [&] {
    if (!d.queries()) {
      const cl_mem_flags in = CL_MEM_READ_ONLY | CL_MEM_ALLOC_HOST_PTR;
      d.queries = dev.allocate(kChunk * stride * sizeof(float), in);
      d.consts = dev.allocate(kChunk * 6 * sizeof(float), in);
      d.scratch = dev.allocate(kChunk * scratch * sizeof(float));
    }
    if (d.slots < slots) {
      d.candidates = dev.allocate(kChunk * slots * sizeof(uint32_t), CL_MEM_READ_ONLY | CL_MEM_ALLOC_HOST_PTR);
      d.nums = dev.allocate(kChunk * slots * sizeof(float), CL_MEM_READ_ONLY | CL_MEM_ALLOC_HOST_PTR);
      d.bins = dev.allocate(kChunk * slots * sizeof(int), CL_MEM_WRITE_ONLY | CL_MEM_ALLOC_HOST_PTR);
      d.slots = slots;
    }
  });
  for (size_t first = 0; first < queries.size(); first += kChunk) {
    const size_t texels = std::min(kChunk, queries.size() - first);
    opencl_call("scoring a batch of texels against the frozen code-books", [&] {
      {
        const cl_map_flags w = CL_MAP_WRITE_INVALIDATE_REGION;
        Mapped<float> blocks(queue, d.queries, w, texels * stride), consts(queue, d.consts, w, texels * 6);
        Mapped<uint32_t> cand(queue, d.candidates, w, texels * slots);
        std::copy_n(candidates.data() + first * slots, texels * slots, cand.get());
        Mapped<float> num(queue, d.nums, w, texels * slots);
        std::copy_n(nums.data() + first * slots, texels * slots, num.get());
        parallel(texels, [&](size_t t) {
          const FrozenQuery& q = queries[first + t];
          for (size_t p = 0; p < size_t(planes); ++p)
            for (size_t c = 0; c < 3; ++c) {
              const float* st = q.stats.data() + (p * 3 + c) * 2 * n;
              layout.pack(q.texel.data() + c * samples + p * n, st, st + n, search_offset(hdr, int(c)),
                          blocks.get() + t * stride + (p * 3 + c) * layout.block());
            }
          for (size_t c = 0; c < 3; ++c) consts.get()[t * 6 + c] = q.c1[c], consts.get()[t * 6 + 3 + c] = q.c2[c];
        });
      }
      cl::Kernel kernel = dev.kernel("search.cl", "search_texels");
      int a = 0;
      kernel.setArg(a++, d.queries);
      kernel.setArg(a++, d.consts);
      kernel.setArg(a++, d.candidates);
      kernel.setArg(a++, d.nums);
      kernel.setArg(a++, cl_int(texels));
      kernel.setArg(a++, cl_int(slots));
      kernel.setArg(a++, d.plane_p2);
      kernel.setArg(a++, d.plane_i2);
      kernel.setArg(a++, d.plane_f);
      kernel.setArg(a++, d.entry_yy);
      kernel.setArg(a++, cl_int(planes));
      kernel.setArg(a++, d.lum);
      kernel.setArg(a++, d.chroma);
      kernel.setArg(a++, d.inv_count);
      kernel.setArg(a++, cl_int(rows));
      kernel.setArg(a++, cl_int(cols));
      kernel.setArg(a++, cl_int(radius));
      kernel.setArg(a++, cl_int(hdr));
      kernel.setArg(a++, cl_int(keep_));
      kernel.setArg(a++, d.scratch);
      kernel.setArg(a++, d.bins);
      // One texel per work-item and work-group: the work-items share nothing, and PoCL runs the groups
      // on all cores.
      queue.enqueueNDRangeKernel(kernel, cl::NullRange, cl::NDRange(texels), cl::NDRange(1));
      Mapped<int> result(queue, d.bins, CL_MAP_READ, texels * slots);
      std::copy_n(result.get(), texels * slots, out.data() + first * slots);
    });
  }
}

void FrozenSearch::encode(const float* texels, size_t n, P6Entry* out) {
  // With one or two P4 entries there is nothing to abandon, and the batch's fixed host work per texel
  // (packing its query, settling the winner exactly) costs more than the kernel saves.
  if (path_ == SearchPath::Pruned || encoder_.codebooks().p4_index.rows() < 3) encode_pruned(texels, n, out);
  else if (path_ == SearchPath::BatchedMSE) encode_batched_mse(texels, n, out);
  else encode_batched(texels, n, out);
  stats_.texels += n;
}

void FrozenSearch::encode_pruned(const float* texels, size_t n, P6Entry* out) {
  const size_t values = 3 * encoder_.codebooks().grid.samples();
  parallel(n, [&](size_t i) { out[i] = encoder_.encode_frozen(texels + i * values); });
}

std::vector<uint32_t> FrozenSearch::gather(const float* texels, size_t n, size_t* slots) {
  const size_t values = 3 * encoder_.codebooks().grid.samples();
  queries_.resize(n);
  parallel(n, [&](size_t i) { encoder_.frozen_query(texels + i * values, queries_[i]); });
  *slots = n ? queries_[0].candidates.size() : 0;
  std::vector<uint32_t> candidates;
  candidates.reserve(n * *slots);
  for (const auto& q : queries_) {
    if (q.candidates.size() != *slots)
      throw InputError("frozen search: texels of one batch have different candidate counts");
    candidates.insert(candidates.end(), q.candidates.begin(), q.candidates.end());
  }
  return candidates;
}

void FrozenSearch::encode_batched(const float* texels, size_t n, P6Entry* out) {
  auto t0 = std::chrono::steady_clock::now();
  size_t slots;
  const std::vector<uint32_t> candidates = gather(texels, n, &slots);
  const std::vector<FrozenQuery>& queries = queries_;
  const std::vector<int> bin = bins(queries, candidates, slots);
  stats_.batch_seconds += seconds_since(t0);
  stats_.scored += n * slots;

  // Score brackets: a completed candidate's bin; an abandoned one scored below a completed one's
  // lower bound, so it cannot win.
  std::vector<double> lower(n * slots, kAbandoned), upper(n * slots, kAbandoned);
  for (size_t k = 0; k < n * slots; ++k)
    if (bin[k] >= 0) bracket(bin[k], &lower[k], &upper[k]);
  t0 = std::chrono::steady_clock::now();
  std::vector<size_t> settled(n, 0);
  parallel(n, [&](size_t i) {
    const size_t at = i * slots;
    out[i] = settle(encoder_, queries[i], candidates.data() + at, lower.data() + at, upper.data() + at, slots, &settled[i]);
  });
  for (size_t s : settled) stats_.settled += s;
  stats_.settle_seconds += seconds_since(t0);
}

void FrozenSearch::encode_batched_mse(const float* texels, size_t n, P6Entry* out) {
  auto t0 = std::chrono::steady_clock::now();
  size_t slots;
  const std::vector<uint32_t> candidates = gather(texels, n, &slots);
  std::vector<double> error, margin;
  squared_errors(queries_, candidates, slots, &error, &margin);
  stats_.batch_seconds += seconds_since(t0);
  stats_.scored += n * slots;

  // Scores are "higher is better": minus the squared error.
  std::vector<double> lower(n * slots), upper(n * slots);
  for (size_t k = 0; k < n * slots; ++k) lower[k] = -(error[k] + margin[k]), upper[k] = -(error[k] - margin[k]);
  t0 = std::chrono::steady_clock::now();
  std::vector<size_t> settled(n, 0);
  parallel(n, [&](size_t i) {
    const size_t at = i * slots;
    out[i] = settle(encoder_, queries_[i], candidates.data() + at, lower.data() + at, upper.data() + at, slots, &settled[i]);
  });
  for (size_t s : settled) stats_.settled += s;
  stats_.settle_seconds += seconds_since(t0);
}

}  // namespace btfvq
