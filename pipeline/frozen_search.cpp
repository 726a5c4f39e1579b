#include "pipeline/frozen_search.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <thread>

#include "pipeline/error.h"
#include "pipeline/opencl_runtime.h"

namespace btfvq {

// The kernel text is also the reference (see kernels/search.cl).
namespace search_cl {
#define __global
#define SEARCH_REFERENCE 1
#include "kernels/search.cl"
#undef __global
#undef SEARCH_REFERENCE
}  // namespace search_cl

namespace {

// Half-width of the rounding margin around a bin's edges: the kernel, its reference and the exact
// comparison sum the same float products in different orders (differences are ~1e-5 in SSIM).
constexpr double kMargin = 5e-4;

double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

}  // namespace

struct FrozenSearch::Device {
  cl::Buffer plane_p2, plane_i2, plane_f, lum, chroma, inv_count;
};

SearchPath FrozenSearch::preferred() {
  // Measured on leather 64 x 64 (docs/similarity.md): the batch kernel on PoCL still takes ~4x the
  // pruned search's time (it scores every candidate in full and PoCL does not vectorize its loops),
  // so the pruned search stays the default until the kernel is vectorized by hand.
  return SearchPath::Pruned;
}

FrozenSearch::FrozenSearch(const Encoder& encoder, SearchPath path, int threads)
    : encoder_(encoder), path_(path), threads_(std::max(1, threads)) {
  // The histogram brackets SSIM percentiles; the MSE metric keeps the pruned (LAESA) search.
  if (encoder.settings().metric != Metric::SSIM) path_ = SearchPath::Pruned;
  if (path_ == SearchPath::Pruned) return;
  const Codebooks& k = encoder.codebooks();
  const AngularGrid& g = k.grid;
  const WindowGeometry geometry(g.n_alpha, g.n_beta, encoder.settings().window_radius);
  for (int i = 0; i < geometry.size(); ++i) inv_count_.push_back(geometry.inv_count(i));
  for (uint32_t e = 0; e < k.p4_index.rows(); ++e) encoder.p4_planes(e, plane_p2_, plane_i2_, plane_f_);
  keep_ = int(std::floor(encoder.settings().outlier_fraction * double(3 * g.samples()) + 1e-9)) + 1;
  if (path_ == SearchPath::BatchedOpenCL) {
    auto& dev = ComputeDevice::get();
    if (!dev.uses_opencl()) throw DeviceError("the batched OpenCL search needs OpenCL: " + dev.description());
    device_ = std::make_unique<Device>();
    opencl_call("uploading the frozen code-books", [&] {
      device_->plane_p2 = dev.upload(plane_p2_);
      device_->plane_i2 = dev.upload(plane_i2_);
      device_->plane_f = dev.upload(plane_f_);
      device_->lum = dev.upload(encoder.luminance_planes().blocks());
      device_->chroma = dev.upload(encoder.chroma_planes().blocks());
      device_->inv_count = dev.upload(inv_count_);
    });
  }
}

FrozenSearch::~FrozenSearch() = default;

void FrozenSearch::bracket(int bin, double* lower, double* upper) {
  *lower = bin <= 0 ? -1e300 : double(bin) / SEARCH_BINS - kMargin;
  *upper = bin >= SEARCH_BINS - 1 ? 1e300 : double(bin + 1) / SEARCH_BINS + kMargin;
}

template <class F>
void FrozenSearch::parallel(size_t n, F&& f) const {
  const int workers = int(std::min<size_t>(size_t(threads_), std::max<size_t>(n, 1)));
  std::vector<std::thread> pool;
  std::vector<std::exception_ptr> errors(static_cast<size_t>(workers));
  for (int w = 0; w < workers; ++w)
    pool.emplace_back([&, w] {
      try {
        for (size_t i = size_t(w); i < n; i += size_t(workers)) f(i);
      } catch (...) {
        errors[size_t(w)] = std::current_exception();
      }
    });
  for (auto& t : pool) t.join();
  for (auto& e : errors)
    if (e) std::rethrow_exception(e);
}

std::vector<float> FrozenSearch::query_block(const FrozenQuery& q) const {
  const AngularGrid& g = encoder_.codebooks().grid;
  const WindowGeometry geometry(g.n_alpha, g.n_beta, encoder_.settings().window_radius);
  const size_t n = size_t(geometry.size()), planes = size_t(g.n_phi_v * g.n_theta_v), samples = g.samples();
  std::vector<float> block(planes * 3 * 3 * n);
  for (size_t p = 0; p < planes; ++p)
    for (size_t c = 0; c < 3; ++c) {
      float* out = block.data() + (p * 3 + c) * 3 * n;
      const float* v = q.texel.data() + c * samples + p * n;
      std::copy(v, v + n, out);
      geometry.stats(v, out + n, out + 2 * n);
    }
  return block;
}

std::vector<int> FrozenSearch::bins(const std::vector<FrozenQuery>& queries, const std::vector<uint32_t>& candidates,
                                    size_t slots) {
  if (path_ == SearchPath::Pruned) throw InputError("frozen search: the pruned path has no batch");
  const size_t texels = queries.size();
  if (candidates.size() != texels * slots) throw InputError("frozen search: candidates must be texels x slots");
  const AngularGrid& g = encoder_.codebooks().grid;
  const int rows = g.n_alpha, cols = g.n_beta, planes = g.n_phi_v * g.n_theta_v;
  const int radius = encoder_.settings().window_radius, hdr = encoder_.dynamic() == Dynamic::HDR;
  const size_t stride = size_t(planes) * 9 * size_t(rows * cols);
  std::vector<float> blocks(texels * stride), consts(texels * 6);
  parallel(texels, [&](size_t t) {
    const std::vector<float> b = query_block(queries[t]);
    std::copy(b.begin(), b.end(), blocks.begin() + std::ptrdiff_t(t * stride));
    for (int c = 0; c < 3; ++c) {
      consts[t * 6 + size_t(c)] = queries[t].c1[c];
      consts[t * 6 + 3 + size_t(c)] = queries[t].c2[c];
    }
  });
  for (uint32_t e : candidates)
    if (e >= encoder_.codebooks().p4_index.rows()) throw InputError("frozen search: candidate past the end of P4");
  std::vector<int> out(texels * slots);
  if (out.empty()) return out;
  if (path_ == SearchPath::BatchedReference) {
    const float* lum = encoder_.luminance_planes().blocks().data();
    const float* chroma = encoder_.chroma_planes().blocks().data();
    parallel(out.size(), [&](size_t id) {
      const size_t t = id / slots, e = size_t(candidates[id]) * size_t(planes);
      out[id] = search_cl::search_bin_item(blocks.data() + t * stride, consts.data() + t * 6, plane_p2_.data() + e,
                                           plane_i2_.data() + e, plane_f_.data() + e, lum, chroma, inv_count_.data(),
                                           rows, cols, radius, planes, hdr, keep_);
    });
    return out;
  }
  auto& dev = ComputeDevice::get();
  opencl_call("scoring a batch of texels against the frozen code-books", [&] {
    cl::Buffer q = dev.upload(blocks), k = dev.upload(consts), cand = dev.upload(candidates);
    cl::Buffer result = dev.allocate(out.size() * sizeof(int), CL_MEM_WRITE_ONLY);
    cl::Kernel kernel = dev.kernel("search.cl", "search_bins");
    int a = 0;
    kernel.setArg(a++, q);
    kernel.setArg(a++, k);
    kernel.setArg(a++, cand);
    kernel.setArg(a++, cl_int(texels));
    kernel.setArg(a++, cl_int(slots));
    kernel.setArg(a++, device_->plane_p2);
    kernel.setArg(a++, device_->plane_i2);
    kernel.setArg(a++, device_->plane_f);
    kernel.setArg(a++, cl_int(planes));
    kernel.setArg(a++, device_->lum);
    kernel.setArg(a++, device_->chroma);
    kernel.setArg(a++, device_->inv_count);
    kernel.setArg(a++, cl_int(rows));
    kernel.setArg(a++, cl_int(cols));
    kernel.setArg(a++, cl_int(radius));
    kernel.setArg(a++, cl_int(hdr));
    kernel.setArg(a++, cl_int(keep_));
    kernel.setArg(a++, result);
    dev.queue().enqueueNDRangeKernel(kernel, cl::NullRange, cl::NDRange(out.size()));
    dev.download(result, out);
  });
  return out;
}

void FrozenSearch::encode(const float* texels, size_t n, P6Entry* out) {
  if (path_ == SearchPath::Pruned) encode_pruned(texels, n, out);
  else encode_batched(texels, n, out);
  stats_.texels += n;
}

void FrozenSearch::encode_pruned(const float* texels, size_t n, P6Entry* out) {
  const size_t values = 3 * encoder_.codebooks().grid.samples();
  parallel(n, [&](size_t i) { out[i] = encoder_.encode_frozen(texels + i * values); });
}

void FrozenSearch::encode_batched(const float* texels, size_t n, P6Entry* out) {
  const size_t values = 3 * encoder_.codebooks().grid.samples();
  auto t0 = std::chrono::steady_clock::now();
  std::vector<FrozenQuery> queries(n);
  std::vector<std::vector<uint32_t>> order(n);
  parallel(n, [&](size_t i) {
    queries[i] = encoder_.frozen_query(texels + i * values);
    order[i] = encoder_.frozen_candidates(texels + i * values);
  });
  const size_t slots = n ? order[0].size() : 0;
  std::vector<uint32_t> candidates;
  candidates.reserve(n * slots);
  for (const auto& o : order) {
    if (o.size() != slots) throw InputError("frozen search: texels of one batch have different candidate counts");
    candidates.insert(candidates.end(), o.begin(), o.end());
  }
  const std::vector<int> bin = bins(queries, candidates, slots);
  stats_.batch_seconds += seconds_since(t0);
  stats_.scored += n * slots;

  t0 = std::chrono::steady_clock::now();
  std::vector<size_t> settled(n, 0);
  parallel(n, [&](size_t i) {
    std::vector<double> lower(slots), upper(slots);
    double floor = -1e300;
    for (size_t k = 0; k < slots; ++k) {
      bracket(bin[i * slots + k], &lower[k], &upper[k]);
      floor = std::max(floor, lower[k]);
    }
    // Only candidates whose bracket reaches the best lower bound can win; try the likeliest first.
    std::vector<size_t> keep;
    for (size_t k = 0; k < slots; ++k)
      if (upper[k] >= floor) keep.push_back(k);
    std::stable_sort(keep.begin(), keep.end(), [&](size_t a, size_t b) { return lower[a] > lower[b]; });
    std::vector<uint32_t> pick;
    for (size_t k : keep) pick.push_back(order[i][k]);
    settled[i] = pick.size();
    out[i] = encoder_.encode_frozen_among(texels + i * values, pick, floor);
  });
  for (size_t s : settled) stats_.settled += s;
  stats_.settle_seconds += seconds_since(t0);
}

}  // namespace btfvq
