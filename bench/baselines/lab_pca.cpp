#include "bench/baselines/lab_pca.h"

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

// CIELab of every 8-bit RGB code would be 2^24 entries; the three linearized channels suffice.
RowMatrix channel_matrix(const MeasuredSample& s, int channel) {
  const size_t pairs = s.pair_count();
  RowMatrix x(Eigen::Index(s.texel_count()), Eigen::Index(pairs));
  const uint8_t* d = s.ldr_data().data();
  for (size_t t = 0; t < s.texel_count(); ++t)
    for (size_t p = 0; p < pairs; ++p) {
      const uint8_t* c = d + (t * pairs + p) * 3;
      const CieLab lab = srgb_to_lab({float(c[0]), float(c[1]), float(c[2])});
      x(Eigen::Index(t), Eigen::Index(p)) = float(channel == 0 ? lab.l : channel == 1 ? lab.a : lab.b);
    }
  return x;
}

double srgb_encode(double linear) {
  const double c = std::max(linear, 0.0);
  return 255.0 * (c <= 0.0031308 ? 12.92 * c : 1.055 * std::pow(c, 1.0 / 2.4) - 0.055);
}

double lab_f_inverse(double f) {
  constexpr double delta = 6.0 / 29.0;
  return f > delta ? f * f * f : 3 * delta * delta * (f - 4.0 / 29.0);
}

}  // namespace

uint64_t lab_pca_bytes(size_t texels, size_t pairs, int components) {
  return 3 + uint64_t(components) * ((texels + kRangeBytes) + (pairs + kRangeBytes));
}

std::array<int, 3> greedy_split(const std::array<std::vector<float>, 3>& sigmas, int k) {
  std::array<int, 3> n{0, 0, 0};
  for (int i = 0; i < k; ++i) {
    int best = -1;
    for (int c = 0; c < 3; ++c)
      if (size_t(n[size_t(c)]) < sigmas[size_t(c)].size() &&
          (best < 0 || sigmas[size_t(c)][size_t(n[size_t(c)])] > sigmas[size_t(best)][size_t(n[size_t(best)])]))
        best = c;
    if (best < 0) break;
    ++n[size_t(best)];
  }
  return n;
}

Rgb lab_to_srgb(const CieLab& lab) {
  constexpr double xn = 0.95047, yn = 1.0, zn = 1.08883;
  const double fy = (lab.l + 16) / 116, fx = fy + lab.a / 500, fz = fy - lab.b / 200;
  const double x = xn * lab_f_inverse(fx), y = yn * lab_f_inverse(fy), z = zn * lab_f_inverse(fz);
  // Inverse of the Lindbloom sRGB matrix used by metrics.cpp.
  const double r = 3.2404542 * x - 1.5371385 * y - 0.4985314 * z;
  const double g = -0.9692660 * x + 1.8760108 * y + 0.0415560 * z;
  const double b = 0.0556434 * x - 0.2040259 * y + 1.0572252 * z;
  return {float(srgb_encode(r)), float(srgb_encode(g)), float(srgb_encode(b))};
}

void lab_pca(const MeasuredSample& sample, const std::vector<int>& components, const PointSink& sink) {
  if (sample.is_hdr()) throw InputError("CIELab PCA: only LDR samples are supported");
  if (components.empty()) return;
  for (int c : components)
    if (c < 1) throw InputError("CIELab PCA: component count " + std::to_string(c) + " is below 1");
  const int kmax = *std::max_element(components.begin(), components.end());
  const size_t texels = sample.texel_count(), pairs = sample.pair_count();

  // Each channel may receive all kmax components, so each is decomposed to kmax.
  const auto t0 = std::chrono::steady_clock::now();
  std::array<Components, 3> pca;
  std::array<std::vector<float>, 3> sigmas;
  for (int ch = 0; ch < 3; ++ch) {
    pca[size_t(ch)] = top_components(channel_matrix(sample, ch), kmax, 7 + uint64_t(ch));
    const auto& s = pca[size_t(ch)].sigma;
    sigmas[size_t(ch)].assign(s.data(), s.data() + s.size());
  }
  const double shared = seconds_since(t0);

  for (int k : components) {
    const auto tq = std::chrono::steady_clock::now();
    const std::array<int, 3> split = greedy_split(sigmas, k);
    BaselinePoint p;
    p.method = "CIELab PCA";
    p.setting = "k=" + std::to_string(k) + " (" + std::to_string(split[0]) + "/" + std::to_string(split[1]) + "/" +
                std::to_string(split[2]) + ")";
    p.size = k;
    std::array<Eigen::MatrixXf, 3> w, b;
    p.bytes = 3;
    for (size_t ch = 0; ch < 3; ++ch) {
      w[ch] = pca[ch].weights.leftCols(split[ch]);
      b[ch] = pca[ch].basis.leftCols(split[ch]);
      for (int i = 0; i < split[ch]; ++i) p.bytes += quantize8(w[ch].col(i)) + quantize8(b[ch].col(i));
    }
    p.seconds = shared + seconds_since(tq);

    std::vector<std::vector<Direction>> lights;
    for (size_t v = 0; v < sample.view_count(); ++v) lights.push_back(sample.lights(v));
    p.decoded = MeasuredSample(sample.width(), sample.height(), sample.views(), lights, Dynamic::LDR);
    uint8_t* out = p.decoded.ldr_data().data();
    constexpr Eigen::Index kBlock = 256;  // texels per block: three block x pairs matrices
    for (Eigen::Index t0b = 0; t0b < Eigen::Index(texels); t0b += kBlock) {
      const Eigen::Index n = std::min<Eigen::Index>(kBlock, Eigen::Index(texels) - t0b);
      std::array<RowMatrix, 3> rec;
      for (size_t ch = 0; ch < 3; ++ch)
        rec[ch] = split[ch] > 0 ? RowMatrix(w[ch].middleRows(t0b, n) * b[ch].transpose())
                                : RowMatrix(RowMatrix::Zero(n, Eigen::Index(pairs)));
      for (Eigen::Index t = 0; t < n; ++t)
        for (size_t q = 0; q < pairs; ++q) {
          const Eigen::Index j = Eigen::Index(q);
          const Rgb c = lab_to_srgb({rec[0](t, j), rec[1](t, j), rec[2](t, j)});
          uint8_t* o = out + ((size_t(t0b + t)) * pairs + q) * 3;
          o[0] = uint8_t(std::clamp(std::lround(c.r), 0L, 255L));
          o[1] = uint8_t(std::clamp(std::lround(c.g), 0L, 255L));
          o[2] = uint8_t(std::clamp(std::lround(c.b), 0L, 255L));
        }
    }
    sink(p);
  }
}

}  // namespace btfvq::baselines
