#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <random>
#include <vector>

#include "pipeline/util/config.h"
#include <btfvq/error.h>
#include "pipeline/encode/similarity.h"

using namespace btfvq;

namespace {

// Independent SSIM percentile: direct window loops in double, sorted values.
double naive_ssim_percentile(const std::vector<float>& x, const std::vector<float>& y, int planes, int rows, int cols,
                             int first_channel, int channels, double L_lum, Dynamic dyn) {
  std::vector<double> values;
  for (int c = 0; c < channels; ++c) {
    const double L = (dyn == Dynamic::HDR && first_channel + c == 0) ? L_lum : 255.0;
    const double C1 = (0.01 * L) * (0.01 * L), C2 = (0.03 * L) * (0.03 * L);
    for (int p = 0; p < planes; ++p) {
      const size_t base = (size_t(c) * planes + p) * size_t(rows * cols);
      for (int r = 0; r < rows; ++r)
        for (int k = 0; k < cols; ++k) {
          double sx = 0, sy = 0, sxx = 0, syy = 0, sxy = 0;
          int n = 0;
          for (int rr = std::max(0, r - 1); rr <= std::min(rows - 1, r + 1); ++rr)
            for (int kk = std::max(0, k - 1); kk <= std::min(cols - 1, k + 1); ++kk) {
              const double a = x[base + size_t(rr * cols + kk)], b = y[base + size_t(rr * cols + kk)];
              sx += a, sy += b, sxx += a * a, syy += b * b, sxy += a * b, ++n;
            }
          const double mx = sx / n, my = sy / n;
          const double vx = sxx / n - mx * mx, vy = syy / n - my * my, cv = sxy / n - mx * my;
          values.push_back((2 * mx * my + C1) * (2 * cv + C2) / ((mx * mx + my * my + C1) * (vx + vy + C2)));
        }
    }
  }
  std::sort(values.begin(), values.end());
  return values[size_t(std::floor(0.02 * double(values.size())))];
}

std::vector<float> random_slice(std::mt19937& rng, size_t n, float lo, float hi) {
  std::uniform_real_distribution<float> u(lo, hi);
  std::vector<float> v(n);
  for (auto& e : v) e = u(rng);
  return v;
}

}  // namespace

TEST_CASE("window geometry: truncated 3x3 windows (4 at corners, 6 on edges, 9 inside), 3 along beta in 1D") {
  WindowGeometry g(11, 11, 1);
  CHECK(g.inv_count(0) == doctest::Approx(1.0 / 4));
  CHECK(g.inv_count(5) == doctest::Approx(1.0 / 6));
  CHECK(g.inv_count(12) == doctest::Approx(1.0 / 9));
  CHECK(g.inv_count(120) == doctest::Approx(1.0 / 4));
  WindowGeometry r(1, 11, 1);
  CHECK(r.inv_count(0) == doctest::Approx(1.0 / 2));
  CHECK(r.inv_count(5) == doctest::Approx(1.0 / 3));
  std::vector<float> v(121, 0.0f), out(121), tmp(121);
  v[0] = 1;  // a unit impulse in the corner reaches its 2x2 neighbourhood only
  g.box(v.data(), out.data(), tmp.data());
  CHECK(out[0] == 1);
  CHECK(out[1] == 1);
  CHECK(out[11] == 1);
  CHECK(out[12] == 1);
  CHECK(out[2] == 0);
  CHECK(out[22] == 0);
}

TEST_CASE("identical slices have similarity 1 and MSE 0") {
  std::mt19937 rng(3);
  WindowGeometry g(11, 11, 1);
  const auto x = random_slice(rng, 3 * 2 * 121, 16, 235);
  SimilaritySettings s = SimilaritySettings::defaults();
  CHECK(slice_similarity(s, Dynamic::LDR, g, x.data(), x.data(), 2, 0, 3, 255) == doctest::Approx(1.0).epsilon(1e-5));
  s.metric = Metric::MSE;
  CHECK(slice_similarity(s, Dynamic::LDR, g, x.data(), x.data(), 2, 0, 3, 255) == doctest::Approx(0.0));
}

TEST_CASE("SSIM percentile agrees with a direct double-precision implementation") {
  std::mt19937 rng(7);
  SimilaritySettings s = SimilaritySettings::defaults();
  for (int trial = 0; trial < 20; ++trial) {
    const bool hdr = trial % 4 == 3;
    const int rows = trial % 5 == 4 ? 1 : 11;
    const int planes = 1 + trial % 3, channels = 1 + trial % 3, first = channels == 3 ? 0 : trial % 2;
    WindowGeometry g(rows, 11, 1);
    const size_t n = size_t(planes * channels * rows * 11);
    auto x = random_slice(rng, n, 20, 200);
    auto y = x;
    std::normal_distribution<float> noise(0.0f, 5.0f + 10.0f * float(trial % 4));
    for (auto& e : y) e += noise(rng);
    const double L = hdr ? 180.0 : 255.0;
    const double expect = naive_ssim_percentile(x, y, planes, rows, 11, first, channels, L,
                                                hdr ? Dynamic::HDR : Dynamic::LDR);
    const double got = slice_similarity(s, hdr ? Dynamic::HDR : Dynamic::LDR, g, x.data(), y.data(), planes, first,
                                        channels, float(L));
    CHECK(got == doctest::Approx(expect).epsilon(2e-4));
    CHECK(got < 1.0);
  }
}

TEST_CASE("the score is the 2nd percentile: r = floor(0.02 n) values may be worse") {
  SimilaritySettings s = SimilaritySettings::defaults();
  ScoreAccumulator acc;
  std::vector<float> v(150, 0.99f);  // n = 150 -> r = 3
  v[10] = 0.1f, v[20] = 0.2f, v[30] = 0.3f;
  acc.reset(Metric::SSIM, v.size(), s.outlier_fraction, -1e300);
  acc.add_ssim(v.data(), int(v.size()));
  CHECK(acc.score() == doctest::Approx(0.99));
  v[40] = 0.4f;  // a 4th outlier becomes the percentile
  acc.reset(Metric::SSIM, v.size(), s.outlier_fraction, -1e300);
  acc.add_ssim(v.data(), int(v.size()));
  CHECK(acc.score() == doctest::Approx(0.4));
}

TEST_CASE("the score is the (r+1)-th smallest of every value added, however they come in") {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (size_t total : {121u, 363u, 2541u, 40656u})
    for (int chunk : {1, 121, 363, 1000}) {
      std::vector<float> v(total);
      for (float& x : v) x = u(rng);
      if (total > 1000) std::fill(v.begin() + 500, v.begin() + 900, 0.25f);  // ties
      if (chunk == 121) std::sort(v.begin(), v.end(), std::greater<>());  // each value below every kept one
      ScoreAccumulator acc;
      acc.reset(Metric::SSIM, total, 0.02, -1e300);
      for (size_t at = 0; at < total; at += size_t(chunk))
        REQUIRE(acc.add_ssim(v.data() + at, int(std::min(total - at, size_t(chunk)))));
      std::vector<float> sorted = v;
      std::sort(sorted.begin(), sorted.end());
      const size_t r = size_t(std::floor(0.02 * double(total) + 1e-9));
      CHECK(acc.score() == double(sorted[r]));
    }
}

TEST_CASE("pruning: a candidate dies exactly when more than r values fall below the bound") {
  std::vector<float> v(100, 0.95f);  // r = 2
  ScoreAccumulator acc;
  v[0] = v[1] = 0.5f;
  acc.reset(Metric::SSIM, v.size(), 0.02, 0.9);
  CHECK(acc.add_ssim(v.data(), 50));
  CHECK(acc.add_ssim(v.data() + 50, 50));
  CHECK(acc.score() >= 0.9);
  v[2] = 0.5f;
  acc.reset(Metric::SSIM, v.size(), 0.02, 0.9);
  CHECK_FALSE(acc.add_ssim(v.data(), 50));  // already 3 values below 0.9
  acc.reset(Metric::MSE, 10, 0.02, -5.0);
  CHECK(acc.add_squared_error(4.0));
  CHECK_FALSE(acc.add_squared_error(2.0));
}

TEST_CASE("SSIM is computed in absolute units: a scaled copy is not identical, a small scale error is close") {
  std::mt19937 rng(11);
  WindowGeometry g(11, 11, 1);
  const auto x = random_slice(rng, 121, 40, 200);
  std::vector<float> far(121), near(121);
  for (size_t i = 0; i < 121; ++i) {
    far[i] = 16 + 0.5f * (x[i] - 16);
    near[i] = 16 + 0.99f * (x[i] - 16);
  }
  SimilaritySettings s = SimilaritySettings::defaults();
  const double a = slice_similarity(s, Dynamic::LDR, g, x.data(), far.data(), 1, 0, 1, 255);
  const double b = slice_similarity(s, Dynamic::LDR, g, x.data(), near.data(), 1, 0, 1, 255);
  CHECK(a < 0.9);
  CHECK(b > 0.99);
}

TEST_CASE("similarity settings come from the config with every default, and bad values are ConfigErrors") {
  auto d = ParameterDictionary::embedded_default("pipeline");
  const SimilaritySettings s = SimilaritySettings::from(d);
  CHECK(s.metric == Metric::SSIM);
  CHECK(s.outlier_fraction == doctest::Approx(0.02));
  CHECK(s.window_radius == 1);
  CHECK(s.pruning);
  for (const char* bad : {R"({"similarity": {"metric": "psnr"}})", R"({"similarity": {"outlier_fraction": -0.1}})",
                          R"({"similarity": {"k1": "x"}})", R"({"similarity": {"window_radius": 9}})",
                          R"({"similarity": {"outlier_fraction": 0.9}})"}) {
    auto e = ParameterDictionary::embedded_default("pipeline");
    e.merge(ParameterDictionary::parse(bad, "override"));
    CHECK_THROWS_AS(SimilaritySettings::from(e), ConfigError);
  }
  auto u = ParameterDictionary::embedded_default("pipeline");
  u.merge(ParameterDictionary::parse(R"({"similarity": {"metirc": "mse"}})", "override"));
  SimilaritySettings::from(u);
  try {
    u.check_unused();
    FAIL("expected ConfigError");
  } catch (const ConfigError& e) {
    CHECK(std::string(e.what()).find("similarity.metirc") != std::string::npos);
  }
}

TEST_CASE("min_ssim_row gives the accumulator's values and stops below the bound") {
  std::mt19937 rng(5);
  WindowGeometry g(1, 11, 1);
  std::vector<float> st(44), scratch(33);
  for (int trial = 0; trial < 50; ++trial) {
    const auto x = random_slice(rng, 11, 16, 235);
    auto y = x;
    std::normal_distribution<float> noise(0.0f, float(trial % 10));
    for (auto& v : y) v += noise(rng);
    ChannelView xv, yv;
    xv.v = x.data(), yv.v = y.data();
    g.stats(x.data(), st.data(), st.data() + 11);
    g.stats(y.data(), st.data() + 22, st.data() + 33);
    xv.mean = st.data(), xv.var = st.data() + 11, yv.mean = st.data() + 22, yv.var = st.data() + 33;
    const Affine ax{-4.0f, 1.25f}, ay{-3.0f, 1.2f};
    ScoreAccumulator acc;
    acc.reset(Metric::SSIM, 11, 0.02, -1e300);
    accumulate_channel(g, Metric::SSIM, xv, ax, yv, ay, 42.0f, 380.0f, acc, scratch.data());
    double fast = 0;
    REQUIRE(min_ssim_row(g, xv, ax, yv, ay, 42.0f, 380.0f, -1e300, &fast));
    CHECK(fast == acc.score());  // bit-identical
    CHECK_FALSE(min_ssim_row(g, xv, ax, yv, ay, 42.0f, 380.0f, std::nextafter(acc.score(), 2.0), &fast));
    CHECK(min_ssim_row(g, xv, ax, yv, ay, 42.0f, 380.0f, acc.score(), &fast));
  }
}
