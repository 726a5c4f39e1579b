#include <doctest/doctest.h>

#include <cmath>
#include <random>

#include "pipeline/parametrization.h"

using namespace btfvq;

TEST_CASE("grid nodes are those of docs/btfbase-format.md") {
  AngularGrid g;
  CHECK(g.beta_node(0) == doctest::Approx(-90.0));
  CHECK(g.beta_node(5) == doctest::Approx(0.0));
  CHECK(g.beta_node(10) == doctest::Approx(90.0));
  CHECK(g.beta_node(6) == doctest::Approx(std::asin(0.2) / kDeg));  // uniform in sin(beta)
  CHECK(g.alpha_node(0) == doctest::Approx(-90.0));
  CHECK(g.alpha_node(1) == doctest::Approx(-72.0));  // 18 degree steps
  CHECK(g.theta_v_node(1) == doctest::Approx(15.0));
  CHECK(g.phi_v_node(1) == doctest::Approx(22.5));
  CHECK(g.samples() == 13552);
}

TEST_CASE("cells: clamping at the ends, last theta node alone, phi wraps") {
  AngularGrid g;
  auto c = g.beta_cell(90.0);
  CHECK(c.i0 == 9);
  CHECK(c.w == doctest::Approx(1.0));
  c = g.theta_v_cell(90.0);
  CHECK((c.i0 == 6 && c.i1 == 6 && c.w == 0.0));
  c = g.theta_v_cell(37.5);
  CHECK((c.i0 == 2 && c.i1 == 3));
  CHECK(c.w == doctest::Approx(0.5));
  c = g.phi_v_cell(350.0);
  CHECK((c.i0 == 15 && c.i1 == 0));
  CHECK(c.w == doctest::Approx((350.0 - 337.5) / 22.5));
  c = g.alpha_cell(-81.0);
  CHECK((c.i0 == 0 && c.i1 == 1));
  CHECK(c.w == doctest::Approx(0.5));
}

TEST_CASE("(theta, phi) -> (alpha, beta) -> (theta, phi) round trips to 1e-5 rad") {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> th(0.0, 89.0), ph(0.0, 360.0);
  int tested = 0;
  for (int i = 0; i < 20000; ++i) {
    const Direction light{th(rng), ph(rng)};
    const double phi_v = ph(rng);
    const OnionAngles a = to_onion(light, phi_v);
    CHECK(std::abs(a.alpha) <= 90.0);
    CHECK(std::abs(a.beta) <= 90.0);
    const Direction back = from_onion(a, phi_v);
    CHECK(angle_between(light, back) < 1e-5);
    ++tested;
  }
  CHECK(tested == 20000);
}

TEST_CASE("the mirror direction lies on beta = 0 and the light opposite the view at beta = -90") {
  // phi' = phi_i - phi_v - 90: a light at the view's own azimuth has phi' = -90, so x = 0, beta = 0.
  const OnionAngles a = to_onion({30.0, 40.0}, 40.0);
  CHECK(a.beta == doctest::Approx(0.0).epsilon(1e-9));
  CHECK(a.alpha == doctest::Approx(-30.0));
  const OnionAngles b = to_onion({30.0, 220.0}, 40.0);
  CHECK(b.beta == doctest::Approx(0.0).epsilon(1e-9));
  CHECK(b.alpha == doctest::Approx(30.0));
  const OnionAngles n = to_onion({0.0, 0.0}, 123.0);  // the normal is the pole E
  CHECK(n.alpha == doctest::Approx(0.0));
  CHECK(n.beta == doctest::Approx(0.0));
}
