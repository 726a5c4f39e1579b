#include <doctest/doctest.h>

#include <random>

#include <btfvq/colour.h>

using namespace btfvq;

TEST_CASE("BT.601 studio swing: black, white and the original decoder's inverse") {
  auto k = rgb_to_ycbcr({0, 0, 0});
  CHECK(k.y == doctest::Approx(16.0));
  CHECK(k.cb == doctest::Approx(128.0));
  auto w = rgb_to_ycbcr({255, 255, 255});
  CHECK(w.y == doctest::Approx(235.0));
  CHECK(w.cr == doctest::Approx(128.0));
  auto back = ycbcr_to_rgb({235, 128, 128});
  CHECK(back.r == doctest::Approx(255.0).epsilon(0.001));
}

TEST_CASE("YCbCr round trips over the 8-bit cube") {
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(0, 255);
  for (int i = 0; i < 10000; ++i) {
    Rgb c{u(rng), u(rng), u(rng)};
    Rgb r = ycbcr_to_rgb(rgb_to_ycbcr(c));
    CHECK(r.r == doctest::Approx(c.r).epsilon(2e-4).scale(255));
    CHECK(r.g == doctest::Approx(c.g).epsilon(2e-4).scale(255));
    CHECK(r.b == doctest::Approx(c.b).epsilon(2e-4).scale(255));
  }
}

TEST_CASE("LogLuv round trips over five decades of linear radiance") {
  std::mt19937 rng(2);
  std::uniform_real_distribution<float> e(-3, 2), u(0.05f, 1.0f);
  for (int i = 0; i < 10000; ++i) {
    const float s = std::pow(10.0f, e(rng));
    Rgb c{s * u(rng), s * u(rng), s * u(rng)};
    Rgb r = from_coding_space(to_coding_space(c, true), true);
    CHECK(r.r == doctest::Approx(c.r).epsilon(1e-3));
    CHECK(r.g == doctest::Approx(c.g).epsilon(1e-3));
    CHECK(r.b == doctest::Approx(c.b).epsilon(1e-3));
  }
  const LogLuv white = rgb_to_logluv({1, 1, 1});
  CHECK(white.log2_y == doctest::Approx(0.0).epsilon(1e-5));
  CHECK(white.u == doctest::Approx(0.1978).epsilon(1e-3));
  CHECK(white.v == doctest::Approx(0.4683).epsilon(1e-3));
}
