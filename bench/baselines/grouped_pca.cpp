#include "bench/baselines/grouped_pca.h"

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

// Columns of a group: (view, light, channel) in order.
struct Column {
  size_t pair;
  int channel;
};

std::vector<Column> group_columns(const MeasuredSample& s, const std::vector<size_t>& views) {
  std::vector<Column> cols;
  for (size_t v : views)
    for (size_t l = 0; l < s.lights(v).size(); ++l)
      for (int c = 0; c < 3; ++c) cols.push_back({s.pair_index(v, l), c});
  return cols;
}

struct GroupModel {
  std::vector<Column> columns;
  Eigen::VectorXf row_mean;  // texels
  Components pca;
};

}  // namespace

std::vector<std::vector<size_t>> view_groups(size_t views, int k) {
  if (k < 1) throw InputError("grouped PCA: group size " + std::to_string(k) + " is below 1");
  std::vector<std::vector<size_t>> groups;
  for (size_t v = 0; v < views; ++v) {
    if (v % size_t(k) == 0) groups.emplace_back();
    groups.back().push_back(v);
  }
  return groups;
}

uint64_t grouped_pca_bytes(size_t texels, size_t values, int components) {
  return (texels + kRangeBytes) + uint64_t(components) * ((texels + kRangeBytes) + (values + kRangeBytes));
}

void grouped_pca(const MeasuredSample& sample, int k, const std::vector<int>& components, const PointSink& sink) {
  if (sample.is_hdr()) throw InputError("grouped PCA: only LDR samples are supported");
  if (components.empty()) return;
  for (int c : components)
    if (c < 1) throw InputError("grouped PCA: component count " + std::to_string(c) + " is below 1");
  const int cmax = *std::max_element(components.begin(), components.end());
  const size_t texels = sample.texel_count(), pairs = sample.pair_count();
  const uint8_t* in = sample.ldr_data().data();

  const auto t0 = std::chrono::steady_clock::now();
  std::vector<GroupModel> models;
  uint64_t seed = 1;
  for (const auto& views : view_groups(sample.view_count(), k)) {
    GroupModel m;
    m.columns = group_columns(sample, views);
    RowMatrix x(Eigen::Index(texels), Eigen::Index(m.columns.size()));
    for (size_t t = 0; t < texels; ++t)
      for (size_t j = 0; j < m.columns.size(); ++j)
        x(Eigen::Index(t), Eigen::Index(j)) = float(in[(t * pairs + m.columns[j].pair) * 3 + size_t(m.columns[j].channel)]);
    m.row_mean = x.rowwise().mean();
    x.colwise() -= m.row_mean;
    m.pca = top_components(x, cmax, seed++);
    models.push_back(std::move(m));
  }
  const double shared = seconds_since(t0);

  for (int c : components) {
    BaselinePoint p;
    p.method = "grouped PCA (k=" + std::to_string(k) + ")";
    p.setting = "C=" + std::to_string(c);
    p.size = c;
    std::vector<std::vector<Direction>> lights;
    for (size_t v = 0; v < sample.view_count(); ++v) lights.push_back(sample.lights(v));
    p.decoded = MeasuredSample(sample.width(), sample.height(), sample.views(), lights, Dynamic::LDR);
    uint8_t* out = p.decoded.ldr_data().data();
    double quantize_seconds = 0;
    for (const GroupModel& m : models) {
      const auto tq = std::chrono::steady_clock::now();
      const Eigen::Index kc = std::min<Eigen::Index>(c, m.pca.basis.cols());
      Eigen::VectorXf mean = m.row_mean;
      Eigen::MatrixXf w = m.pca.weights.leftCols(kc), b = m.pca.basis.leftCols(kc);
      p.bytes += quantize8(mean);
      for (Eigen::Index i = 0; i < kc; ++i) p.bytes += quantize8(w.col(i)) + quantize8(b.col(i));
      p.bytes += uint64_t(c - kc) * (texels + m.columns.size() + 2 * kRangeBytes);  // fixed-C format
      quantize_seconds += seconds_since(tq);
      RowMatrix xr = w * b.transpose();
      xr.colwise() += mean;
      for (size_t t = 0; t < texels; ++t)
        for (size_t j = 0; j < m.columns.size(); ++j)
          out[(t * pairs + m.columns[j].pair) * 3 + size_t(m.columns[j].channel)] =
              uint8_t(std::clamp(std::lround(xr(Eigen::Index(t), Eigen::Index(j))), 0L, 255L));
    }
    p.seconds = shared + quantize_seconds;
    sink(p);
  }
}

}  // namespace btfvq::baselines
