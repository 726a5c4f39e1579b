// The rate-distortion bench's competitors (bench/baselines): their linear algebra, their byte counts
// and that each reconstructs what it can represent.
#include <doctest/doctest.h>

#include <cmath>
#include <cstdint>
#include <vector>

#include "bench/baselines/grouped_pca.h"
#include "bench/baselines/lab_pca.h"
#include "bench/baselines/pca.h"
#include "bench/baselines/per_view_pca.h"
#include "bench/baselines/texel_vq.h"
#include "pipeline/encode/ceiling.h"
#include "pipeline/util/config.h"
#include <btfvq/error.h>
#include "pipeline/metrics/metrics.h"

using namespace btfvq;
using namespace btfvq::baselines;

namespace {

// A 4 x 4 Bonn sample of pseudo-random values (a fixed LCG, so every platform sees the same bytes).
MeasuredSample noise_sample() {
  MeasuredSample s = make_bonn_sample(4, 4, Dynamic::LDR);
  uint32_t x = 12345;
  for (auto& v : s.ldr_data()) {
    x = x * 1664525u + 1013904223u;
    v = uint8_t(40 + (x >> 24) % 160);
  }
  return s;
}

// A 4 x 4 sample whose texels each have one colour in every direction: the left half `a`, the right `b`.
MeasuredSample two_colour_sample(Rgb a, Rgb b) {
  MeasuredSample s = make_bonn_sample(4, 4, Dynamic::LDR);
  for (size_t t = 0; t < s.texel_count(); ++t) {
    const Rgb c = (t % 4) < 2 ? a : b;
    for (size_t p = 0; p < s.pair_count(); ++p) {
      uint8_t* o = s.ldr_data().data() + (t * s.pair_count() + p) * 3;
      o[0] = uint8_t(c.r), o[1] = uint8_t(c.g), o[2] = uint8_t(c.b);
    }
  }
  return s;
}

int max_abs_difference(const MeasuredSample& a, const MeasuredSample& b) {
  REQUIRE(a.ldr_data().size() == b.ldr_data().size());
  int m = 0;
  for (size_t i = 0; i < a.ldr_data().size(); ++i) m = std::max(m, std::abs(int(a.ldr_data()[i]) - int(b.ldr_data()[i])));
  return m;
}

double psnr_of(const MeasuredSample& a, const MeasuredSample& b) { return psnr(a.ldr_data(), b.ldr_data()); }

}  // namespace

TEST_CASE("quantize8 keeps the vector's range and rounds to 255 steps") {
  Eigen::VectorXf v(4);
  v << -1.0f, 0.1f, 0.3f, 1.0f;
  CHECK(quantize8(v) == 4 + 8);
  CHECK(v(0) == doctest::Approx(-1.0));
  CHECK(v(3) == doctest::Approx(1.0));
  // step 2/255: 0.1 -> code 140.25 -> 140; 0.3 -> code 165.75 -> 166.
  CHECK(v(1) == doctest::Approx(-1.0 + 140.0 * 2.0 / 255.0));
  CHECK(v(2) == doctest::Approx(-1.0 + 166.0 * 2.0 / 255.0));
  Eigen::VectorXf flat = Eigen::VectorXf::Constant(3, 7.0f);
  CHECK(quantize8(flat) == 3 + 8);
  CHECK(flat(1) == 7.0f);
}

TEST_CASE("top_components of a tiny known matrix: singular values 4 and 3") {
  RowMatrix x(3, 2);
  x << 3, 0, 0, 4, 0, 0;
  const Components c = top_components(x, 2);
  REQUIRE(c.sigma.size() == 2);
  CHECK(c.sigma(0) == doctest::Approx(4.0));
  CHECK(c.sigma(1) == doctest::Approx(3.0));
  CHECK(std::abs(c.basis(1, 0)) == doctest::Approx(1.0));  // the first direction is the second axis
  const RowMatrix r = c.weights * c.basis.transpose();
  CHECK((r - x).cwiseAbs().maxCoeff() < 1e-5f);
}

TEST_CASE("the randomized path recovers a rank-3 matrix wider than the exact limit") {
  const Eigen::Index n = 40, d = kExactGramLimit + 500;
  Eigen::MatrixXf u = Eigen::MatrixXf::Zero(n, 3), v = Eigen::MatrixXf::Zero(d, 3);
  for (Eigen::Index i = 0; i < n; ++i) u(i, i % 3) = 1.0f;  // disjoint supports: orthogonal
  for (Eigen::Index j = 0; j < d; ++j) v(j, (j / 7) % 3) = 1.0f;
  u.colwise().normalize();
  v.colwise().normalize();
  const float s[3] = {10.0f, 5.0f, 1.0f};
  const RowMatrix x = u * Eigen::Vector3f(s[0], s[1], s[2]).asDiagonal() * v.transpose();
  const Components c = top_components(x, 3);
  for (int i = 0; i < 3; ++i) CHECK(c.sigma(i) == doctest::Approx(s[i]).epsilon(1e-4));
  const RowMatrix r = c.weights * c.basis.transpose();
  CHECK((r - x).cwiseAbs().maxCoeff() < 1e-4f);
}

TEST_CASE("per-view PCA: byte count as documented, full rank reconstructs up to 8-bit quantization") {
  const MeasuredSample s = noise_sample();
  // 81 views x (C x ((16 + 8) + (243 + 8)) + 243 + 8) bytes.
  CHECK(per_view_pca_bytes(16, 243, 2) == 2 * (24 + 251) + 251);
  std::vector<BaselinePoint> points;
  per_view_pca(s, {1, 16}, [&](BaselinePoint& p) { points.push_back(std::move(p)); });
  REQUIRE(points.size() == 2);
  CHECK(points[0].bytes == 81u * (1 * (24 + 251) + 251));
  CHECK(points[1].bytes == 81u * (16 * (24 + 251) + 251));
  // 16 texels centred on their mean have rank <= 15: 16 components represent every view exactly,
  // so what is left is the 8-bit storage of the factors (well under one grey level on average).
  CHECK(psnr_of(s, points[1].decoded) > 45.0);
  CHECK(psnr_of(s, points[0].decoded) < 25.0);
  CHECK_THROWS_AS(per_view_pca(s, {0}, [](BaselinePoint&) {}), InputError);
}

TEST_CASE("grouped PCA: groups of neighbouring views, byte count, full rank reconstruction") {
  const auto groups = view_groups(81, 3);
  CHECK(groups.size() == 27);
  CHECK(groups[1] == std::vector<size_t>{3, 4, 5});
  CHECK(view_groups(5, 3).back() == std::vector<size_t>{3, 4});
  const MeasuredSample s = noise_sample();
  CHECK(grouped_pca_bytes(16, 729, 2) == 24 + 2 * (24 + 737));
  std::vector<BaselinePoint> points;
  grouped_pca(s, 3, {2, 16}, [&](BaselinePoint& p) { points.push_back(std::move(p)); });
  REQUIRE(points.size() == 2);
  CHECK(points[0].bytes == 27u * (24 + 2 * (24 + 737)));
  CHECK(psnr_of(s, points[1].decoded) > 45.0);
  CHECK(psnr_of(s, points[0].decoded) < 25.0);
}

TEST_CASE("CIELab PCA: greedy split, Lab inverse, uniform colours are three components") {
  CHECK(greedy_split({std::vector<float>{10, 5, 1}, {8, 2}, {9, 7, 6}}, 4) == std::array<int, 3>{1, 1, 2});
  CHECK(greedy_split({std::vector<float>{3}, {}, {}}, 2) == std::array<int, 3>{1, 0, 0});
  for (const Rgb c : {Rgb{0, 0, 0}, Rgb{255, 255, 255}, Rgb{200, 30, 90}, Rgb{12, 140, 250}}) {
    const Rgb back = lab_to_srgb(srgb_to_lab(c));
    CHECK(back.r == doctest::Approx(c.r).epsilon(1e-3));
    CHECK(back.g == doctest::Approx(c.g).epsilon(1e-3));
    CHECK(back.b == doctest::Approx(c.b).epsilon(1e-3));
  }
  CHECK(lab_pca_bytes(16, 6561, 2) == 3 + 2 * (24 + 6569));
  // Two colours constant over the directions: each Lab channel matrix has rank 1.
  const MeasuredSample s = two_colour_sample({200, 60, 40}, {40, 120, 220});
  std::vector<BaselinePoint> points;
  lab_pca(s, {1, 3}, [&](BaselinePoint& p) { points.push_back(std::move(p)); });
  REQUIRE(points.size() == 2);
  CHECK(points[1].bytes == 3 + 3 * (24 + 6569));
  CHECK(points[1].setting == "k=3 (1/1/1)");
  CHECK(max_abs_difference(s, points[1].decoded) <= 1);
  CHECK(max_abs_difference(s, points[0].decoded) > 20);
}

TEST_CASE("one-level VQ: a constant texel decodes to its colour; two materials need two code-vectors") {
  const ParameterDictionary config = ParameterDictionary::embedded_default("pipeline");
  const AngularGrid grid{11, 11, 7, 16};
  std::vector<float> texel(3 * grid.samples());
  const YCbCr ycc = rgb_to_ycbcr({180, 90, 60});
  std::fill_n(texel.begin(), grid.samples(), ycc.y);
  std::fill_n(texel.begin() + std::ptrdiff_t(grid.samples()), grid.samples(), ycc.cb);
  std::fill_n(texel.begin() + std::ptrdiff_t(2 * grid.samples()), grid.samples(), ycc.cr);
  for (const auto& [light, view] : {std::pair{Direction{0, 0}, Direction{0, 0}}, std::pair{Direction{75, 345}, Direction{60, 36}},
                                    std::pair{Direction{45, 120}, Direction{30, 60}}}) {
    const Rgb c = evaluate_resampled(texel.data(), grid, light, view);
    CHECK(c.r == doctest::Approx(180).epsilon(1e-3));
    CHECK(c.g == doctest::Approx(90).epsilon(1e-3));
    CHECK(c.b == doctest::Approx(60).epsilon(1e-3));
  }
  CHECK(texel_vq_bytes(16, grid.samples(), 2) == 2 * 3 * (13552 + 8) + 2);
  const MeasuredSample s = two_colour_sample({200, 60, 40}, {40, 120, 220});
  std::vector<BaselinePoint> points;
  texel_vq(s, config, {1, 2}, [&](BaselinePoint& p) { points.push_back(std::move(p)); });
  REQUIRE(points.size() == 2);
  CHECK(points[1].bytes == 2 * 3 * (13552 + 8) + 2);
  CHECK(points[0].bytes == 1 * 3 * (13552 + 8) + 0);
  CHECK(max_abs_difference(s, points[1].decoded) <= 1);
  CHECK(max_abs_difference(s, points[0].decoded) > 50);
  // Resampling reproduces constants and the decoder's interpolation keeps them: the round trip is exact.
  CHECK(max_abs_difference(s, parametrization_roundtrip(s, config)) <= 1);
}
