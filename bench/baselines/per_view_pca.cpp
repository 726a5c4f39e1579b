#include "bench/baselines/per_view_pca.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "bench/baselines/pca.h"
#include <btfvq/error.h>

namespace btfvq::baselines {

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

struct ViewModel {
  Eigen::VectorXf mean;  // values
  Components pca;
};

RowMatrix view_matrix(const MeasuredSample& s, size_t view) {
  const size_t lights = s.lights(view).size(), pairs = s.pair_count(), first = s.pair_index(view, 0);
  RowMatrix x(Eigen::Index(s.texel_count()), Eigen::Index(lights * 3));
  const uint8_t* d = s.ldr_data().data();
  for (size_t t = 0; t < s.texel_count(); ++t)
    for (size_t i = 0; i < lights * 3; ++i) x(Eigen::Index(t), Eigen::Index(i)) = float(d[(t * pairs + first) * 3 + i]);
  return x;
}

}  // namespace

uint64_t per_view_pca_bytes(size_t texels, size_t values, int components) {
  return uint64_t(components) * ((texels + kRangeBytes) + (values + kRangeBytes)) + values + kRangeBytes;
}

void per_view_pca(const MeasuredSample& sample, const std::vector<int>& components, const PointSink& sink) {
  if (sample.is_hdr()) throw InputError("per-view PCA: only LDR samples are supported");
  if (components.empty()) return;
  for (int c : components)
    if (c < 1) throw InputError("per-view PCA: component count " + std::to_string(c) + " is below 1");
  const int cmax = *std::max_element(components.begin(), components.end());
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<ViewModel> models(sample.view_count());
  for (size_t v = 0; v < sample.view_count(); ++v) {
    RowMatrix x = view_matrix(sample, v);
    models[v].mean = x.colwise().mean().transpose();
    x.rowwise() -= models[v].mean.transpose();
    models[v].pca = top_components(x, cmax, 1 + v);
  }
  const double shared = seconds_since(t0);

  const size_t pairs = sample.pair_count();
  for (int c : components) {
    BaselinePoint p;
    p.method = "per-view PCA";
    p.setting = "C=" + std::to_string(c);
    p.size = c;
    std::vector<std::vector<Direction>> lights;
    for (size_t v = 0; v < sample.view_count(); ++v) lights.push_back(sample.lights(v));
    p.decoded = MeasuredSample(sample.width(), sample.height(), sample.views(), lights, Dynamic::LDR);
    double quantize_seconds = 0;
    for (size_t v = 0; v < sample.view_count(); ++v) {
      const auto tq = std::chrono::steady_clock::now();
      const ViewModel& m = models[v];
      const Eigen::Index k = std::min<Eigen::Index>(c, m.pca.basis.cols());
      Eigen::VectorXf mean = m.mean;
      Eigen::MatrixXf w = m.pca.weights.leftCols(k), b = m.pca.basis.leftCols(k);
      p.bytes += quantize8(mean);
      for (Eigen::Index i = 0; i < k; ++i) p.bytes += quantize8(w.col(i)) + quantize8(b.col(i));
      // Components beyond the rank are zero but a fixed-C format stores them all the same.
      p.bytes += uint64_t(c - k) * (sample.texel_count() + sample.lights(v).size() * 3 + 2 * kRangeBytes);
      quantize_seconds += seconds_since(tq);
      RowMatrix xr = w * b.transpose();
      xr.rowwise() += mean.transpose();
      const size_t first = sample.pair_index(v, 0), values = size_t(xr.cols());
      uint8_t* out = p.decoded.ldr_data().data();
      for (size_t t = 0; t < sample.texel_count(); ++t)
        for (size_t i = 0; i < values; ++i)
          out[(t * pairs + first) * 3 + i] =
              uint8_t(std::clamp(std::lround(xr(Eigen::Index(t), Eigen::Index(i))), 0L, 255L));
    }
    p.seconds = shared + quantize_seconds;
    sink(p);
  }
}

}  // namespace btfvq::baselines
