#include "bench/baselines/texel_vq.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "bench/baselines/pca.h"
#include <btfvq/error.h>
#include "pipeline/encode/ceiling.h"
#include "pipeline/encode/resample.h"

namespace btfvq::baselines {

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Index of the nearest code-vector of every row of x (squared Euclidean distance).
std::vector<int> nearest(const RowMatrix& x, const RowMatrix& codebook, const Eigen::VectorXf& norms,
                         std::vector<float>* distance = nullptr) {
  const Eigen::MatrixXf d = (-2.0f * (x * codebook.transpose())).rowwise() + norms.transpose();
  std::vector<int> out(size_t(x.rows()));
  if (distance) distance->resize(size_t(x.rows()));
  for (Eigen::Index i = 0; i < x.rows(); ++i) {
    Eigen::Index j = 0;
    const float m = d.row(i).minCoeff(&j);
    out[size_t(i)] = int(j);
    if (distance) (*distance)[size_t(i)] = m + x.row(i).squaredNorm();
  }
  return out;
}

RowMatrix kmeans(const RowMatrix& train, int entries, int iterations) {
  const Eigen::Index m = train.rows(), n = std::min<Eigen::Index>(entries, m);
  RowMatrix c(n, train.cols());
  for (Eigen::Index j = 0; j < n; ++j) c.row(j) = train.row(j * m / n);
  for (int it = 0; it < iterations; ++it) {
    std::vector<float> dist;
    const auto assign = nearest(train, c, c.rowwise().squaredNorm(), &dist);
    RowMatrix sum = RowMatrix::Zero(n, train.cols());
    std::vector<int> count(size_t(n), 0);
    for (Eigen::Index i = 0; i < m; ++i) {
      sum.row(assign[size_t(i)]) += train.row(i);
      ++count[size_t(assign[size_t(i)])];
    }
    for (Eigen::Index j = 0; j < n; ++j) {
      if (count[size_t(j)] > 0) {
        c.row(j) = sum.row(j) / float(count[size_t(j)]);
      } else {  // an empty cell takes the training vector worst represented so far
        const auto far = std::max_element(dist.begin(), dist.end()) - dist.begin();
        c.row(j) = train.row(far);
        dist[size_t(far)] = 0;
      }
    }
  }
  return c;
}

}  // namespace

uint64_t texel_vq_bytes(size_t texels, size_t samples, int entries) {
  const uint64_t bits = entries <= 1 ? 0 : uint64_t(std::ceil(std::log2(double(entries))));
  return uint64_t(entries) * 3 * (samples + kRangeBytes) + (texels * bits + 7) / 8;
}

void texel_vq(const MeasuredSample& sample, const ParameterDictionary& config, const std::vector<int>& entries,
              const PointSink& sink, const TexelVqOptions& options) {
  if (sample.is_hdr()) throw InputError("one-level VQ: only LDR samples are supported");
  if (entries.empty()) return;
  for (int n : entries)
    if (n < 1) throw InputError("one-level VQ: code-book size " + std::to_string(n) + " is below 1");
  const AngularGrid grid = grid_settings(config);
  const ResampleOperator op(sample, grid, ResampleSettings::from(config));
  const size_t texels = sample.texel_count(), values = op.values_per_texel(), samples = grid.samples();
  constexpr size_t kTile = 256;

  // Pass 1: resample every texel, keep the evenly spaced training texels.
  auto t0 = std::chrono::steady_clock::now();
  const size_t m = std::min(texels, std::max<size_t>(options.training_texels, 1));
  RowMatrix train{Eigen::Index(m), Eigen::Index(values)};
  RowMatrix tile{Eigen::Index(kTile), Eigen::Index(values)};
  for (size_t first = 0, next_i = 0; first < texels; first += kTile) {
    const size_t n = std::min(kTile, texels - first);
    op.apply(sample, first, n, tile.data());
    for (; next_i < m && next_i * texels / m < first + n; ++next_i)
      train.row(Eigen::Index(next_i)) = tile.row(Eigen::Index(next_i * texels / m - first));
  }
  const double resample_seconds = seconds_since(t0);

  // Code-books, quantized as stored (the encoder assigns texels to what the decoder will see).
  std::vector<RowMatrix> books;
  std::vector<Eigen::VectorXf> norms;
  std::vector<double> seconds;
  std::vector<uint64_t> bytes;
  for (int n : entries) {
    t0 = std::chrono::steady_clock::now();
    RowMatrix c = kmeans(train, n, options.iterations);
    uint64_t stored = 0;
    for (Eigen::Index j = 0; j < c.rows(); ++j)
      for (int ch = 0; ch < 3; ++ch) {
        Eigen::VectorXf seg = c.row(j).segment(Eigen::Index(size_t(ch) * samples), Eigen::Index(samples)).transpose();
        stored += quantize8(seg);
        c.row(j).segment(Eigen::Index(size_t(ch) * samples), Eigen::Index(samples)) = seg.transpose();
      }
    stored += uint64_t(n - c.rows()) * 3 * (samples + kRangeBytes);  // a size-n code-book stores n entries
    const uint64_t bits = n <= 1 ? 0 : uint64_t(std::ceil(std::log2(double(n))));
    bytes.push_back(stored + (texels * bits + 7) / 8);
    norms.push_back(c.rowwise().squaredNorm());
    books.push_back(std::move(c));
    seconds.push_back(resample_seconds + seconds_since(t0));
  }
  train.resize(0, 0);

  // Pass 2: every texel to its nearest code-vector of every code-book.
  std::vector<std::vector<int>> index(entries.size(), std::vector<int>(texels));
  std::vector<double> assign_seconds(entries.size(), 0);
  for (size_t first = 0; first < texels; first += kTile) {
    const size_t n = std::min(kTile, texels - first);
    t0 = std::chrono::steady_clock::now();
    op.apply(sample, first, n, tile.data());
    const double rs = seconds_since(t0);
    const RowMatrix x = tile.topRows(Eigen::Index(n));
    for (size_t e = 0; e < entries.size(); ++e) {
      t0 = std::chrono::steady_clock::now();
      const auto near = nearest(x, books[e], norms[e]);
      std::copy(near.begin(), near.end(), index[e].begin() + std::ptrdiff_t(first));
      assign_seconds[e] += rs + seconds_since(t0);
    }
  }

  std::vector<std::vector<Direction>> lights;
  for (size_t v = 0; v < sample.view_count(); ++v) lights.push_back(sample.lights(v));
  const size_t pairs = sample.pair_count();
  for (size_t e = 0; e < entries.size(); ++e) {
    BaselinePoint p;
    p.method = "one-level VQ";
    p.setting = "N=" + std::to_string(entries[e]);
    p.size = entries[e];
    p.bytes = bytes[e];
    p.seconds = seconds[e] + assign_seconds[e];
    // Each code-vector decoded once at every measured pair; texels copy their code-vector's values.
    const RowMatrix& c = books[e];
    std::vector<uint8_t> table(size_t(c.rows()) * pairs * 3);
    for (Eigen::Index j = 0; j < c.rows(); ++j)
      for (size_t v = 0; v < sample.view_count(); ++v)
        for (size_t l = 0; l < lights[v].size(); ++l) {
          const Rgb rgb = evaluate_resampled(c.row(j).data(), grid, lights[v][l], sample.views()[v]);
          uint8_t* o = table.data() + (size_t(j) * pairs + sample.pair_index(v, l)) * 3;
          o[0] = uint8_t(std::clamp(std::lround(rgb.r), 0L, 255L));
          o[1] = uint8_t(std::clamp(std::lround(rgb.g), 0L, 255L));
          o[2] = uint8_t(std::clamp(std::lround(rgb.b), 0L, 255L));
        }
    p.decoded = MeasuredSample(sample.width(), sample.height(), sample.views(), lights, Dynamic::LDR);
    uint8_t* out = p.decoded.ldr_data().data();
    for (size_t t = 0; t < texels; ++t)
      std::copy_n(table.data() + size_t(index[e][t]) * pairs * 3, pairs * 3, out + t * pairs * 3);
    sink(p);
  }
}

}  // namespace btfvq::baselines
