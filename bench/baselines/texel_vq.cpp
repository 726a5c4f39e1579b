#include "bench/baselines/texel_vq.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "bench/baselines/pca.h"
#include <btfvq/error.h>
#include "pipeline/encode/resample.h"

namespace btfvq::baselines {

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

AngularGrid grid_from(const ParameterDictionary& config) {
  AngularGrid g{config.integer("grid.n_beta", 3, 1024), config.integer("grid.n_alpha", 2, 1024),
                config.integer("grid.n_theta_v", 2, 1024), config.integer("grid.n_phi_v", 1, 1024)};
  g.validate();
  return g;
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

Rgb evaluate_resampled(const float* tx, const AngularGrid& grid, const Direction& light, const Direction& view) {
  if (!(light.theta <= 90.0 && view.theta <= 90.0)) return {};
  const int nb = grid.n_beta;
  const size_t samples = grid.samples();
  // Onion angles and cells as Decoder::evaluate_p4 computes them.
  const double phi = relative_light_azimuth(light.phi, view.phi) * kDeg, sin_t = std::sin(light.theta * kDeg);
  const double sb = std::clamp(std::cos(phi) * sin_t, -1.0, 1.0), ly = std::sin(phi) * sin_t;
  const double cos_b = std::sqrt(1.0 - sb * sb);
  const double alpha = cos_b > 0 ? std::asin(std::clamp(ly / cos_b, -1.0, 1.0)) / kDeg : 0.0, beta = std::asin(sb) / kDeg;
  const int bi = std::clamp(int(std::floor((sb + 1.0) / 2.0 * (nb - 1))), 0, nb - 2);
  const double b0 = grid.beta_node(bi), b1 = grid.beta_node(bi + 1);
  const double bw = std::clamp((beta - b0) / (b1 - b0), 0.0, 1.0);
  const Cell ac = grid.alpha_cell(alpha), tc = grid.theta_v_cell(view.theta), pc = grid.phi_v_cell(view.phi);
  // The decoder's cubic Hermite along beta, with its one-sided end tangents.
  const double h01 = -2 * bw * bw * bw + 3 * bw * bw, h00 = 1 - h01, h11 = bw * bw * bw - bw * bw, h10 = h11 - bw * bw + bw;
  auto hermite = [&](const float* s) {
    const double p0 = s[bi], p1 = s[bi + 1];
    const double m0 = bi == 0 ? p1 - p0 : (p1 - double(s[bi - 1])) / 2;
    const double m1 = bi == nb - 2 ? p1 - p0 : (double(s[bi + 1]) - p0) / 2;
    return h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1;
  };
  const int alpha_node[2] = {ac.i0, ac.i1};
  const double alpha_w[2] = {1.0 - ac.w, ac.w};
  const int phi_node[2] = {pc.i0, pc.i1};
  const double phi_w[2] = {1.0 - pc.w, pc.w};
  const int theta_node[2] = {tc.i0, tc.i1};
  const double theta_w[2] = {tc.i0 == tc.i1 ? 1.0 : 1.0 - tc.w, tc.i0 == tc.i1 ? 0.0 : tc.w};
  double r = 0, g = 0, b = 0;
  for (int p = 0; p < 2; ++p) {
    if (phi_w[p] == 0.0) continue;
    for (int t = 0; t < 2; ++t) {
      if (theta_w[t] == 0.0) continue;
      double yy = 0, cb = 0, cr = 0;
      for (int a = 0; a < 2; ++a) {
        const size_t base = grid.index(phi_node[p], theta_node[t], alpha_node[a], 0);
        const double w = alpha_w[a];
        yy += w * hermite(tx + base);
        cb += w * ((1.0 - bw) * double(tx[samples + base + size_t(bi)]) + bw * double(tx[samples + base + size_t(bi) + 1]));
        cr += w * ((1.0 - bw) * double(tx[2 * samples + base + size_t(bi)]) +
                   bw * double(tx[2 * samples + base + size_t(bi) + 1]));
      }
      const Rgb v = from_coding_space({float(yy), float(cb), float(cr)}, false);
      const double s = phi_w[p] * theta_w[t];
      r += s * double(v.r);
      g += s * double(v.g);
      b += s * double(v.b);
    }
  }
  return {float(r), float(g), float(b)};
}

MeasuredSample resampled_roundtrip(const MeasuredSample& sample, const ParameterDictionary& config) {
  if (sample.is_hdr()) throw InputError("resampled round trip: only LDR samples are supported");
  const AngularGrid grid = grid_from(config);
  const ResampleOperator op(sample, grid, ResampleSettings::from(config));
  std::vector<std::vector<Direction>> lights;
  for (size_t v = 0; v < sample.view_count(); ++v) lights.push_back(sample.lights(v));
  MeasuredSample out(sample.width(), sample.height(), sample.views(), lights, Dynamic::LDR);
  constexpr size_t kTile = 64;
  const size_t pairs = sample.pair_count(), values = op.values_per_texel();
  std::vector<float> tile(kTile * values);
  for (size_t first = 0; first < sample.texel_count(); first += kTile) {
    const size_t n = std::min(kTile, sample.texel_count() - first);
    op.apply(sample, first, n, tile.data());
    for (size_t i = 0; i < n; ++i)
      for (size_t v = 0; v < sample.view_count(); ++v)
        for (size_t l = 0; l < lights[v].size(); ++l) {
          const Rgb rgb = evaluate_resampled(tile.data() + i * values, grid, lights[v][l], sample.views()[v]);
          uint8_t* o = out.ldr_data().data() + ((first + i) * pairs + sample.pair_index(v, l)) * 3;
          o[0] = uint8_t(std::clamp(std::lround(rgb.r), 0L, 255L));
          o[1] = uint8_t(std::clamp(std::lround(rgb.g), 0L, 255L));
          o[2] = uint8_t(std::clamp(std::lround(rgb.b), 0L, 255L));
        }
  }
  return out;
}

void texel_vq(const MeasuredSample& sample, const ParameterDictionary& config, const std::vector<int>& entries,
              const PointSink& sink, const TexelVqOptions& options) {
  if (sample.is_hdr()) throw InputError("one-level VQ: only LDR samples are supported");
  if (entries.empty()) return;
  for (int n : entries)
    if (n < 1) throw InputError("one-level VQ: code-book size " + std::to_string(n) + " is below 1");
  const AngularGrid grid = grid_from(config);
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
