#include "pipeline/parametrization.h"

#include <algorithm>
#include <cmath>

#include <btfvq/error.h>

namespace btfvq {

namespace {

double wrap360(double a) {
  a = std::fmod(a, 360.0);
  return a < 0 ? a + 360.0 : a;
}

double asin_deg(double x) { return std::asin(std::clamp(x, -1.0, 1.0)) / kDeg; }

}  // namespace

void AngularGrid::validate() const {
  if (n_beta < 3 || n_alpha < 2 || n_theta_v < 2 || n_phi_v < 1 || n_beta > 1024 || n_alpha > 1024 ||
      n_theta_v > 1024 || n_phi_v > 1024)
    throw InputError("angular grid needs n_beta >= 3, n_alpha >= 2, n_theta_v >= 2, n_phi_v >= 1 (each <= 1024)");
}

double AngularGrid::beta_node(int k) const { return asin_deg(-1.0 + 2.0 * k / (n_beta - 1)); }
double AngularGrid::alpha_node(int k) const { return -90.0 + k * 180.0 / (n_alpha - 1); }
double AngularGrid::theta_v_node(int k) const { return k * 90.0 / (n_theta_v - 1); }
double AngularGrid::phi_v_node(int k) const { return k * 360.0 / n_phi_v; }

Cell AngularGrid::beta_cell(double beta) const {
  const double s = std::sin(beta * kDeg);
  int i = int(std::floor((s + 1.0) / 2.0 * (n_beta - 1)));
  i = std::clamp(i, 0, n_beta - 2);
  const double b0 = beta_node(i), b1 = beta_node(i + 1);
  return {i, i + 1, std::clamp((beta - b0) / (b1 - b0), 0.0, 1.0)};
}

Cell AngularGrid::alpha_cell(double alpha) const {
  const double step = 180.0 / (n_alpha - 1);
  int i = std::clamp(int(std::floor((alpha + 90.0) / step)), 0, n_alpha - 2);
  return {i, i + 1, std::clamp((alpha - alpha_node(i)) / step, 0.0, 1.0)};
}

Cell AngularGrid::theta_v_cell(double theta_v) const {
  const double step = 90.0 / (n_theta_v - 1);
  int i = std::max(0, int(std::floor(theta_v / step)));
  if (i >= n_theta_v - 1) return {n_theta_v - 1, n_theta_v - 1, 0.0};
  return {i, i + 1, std::clamp((theta_v - theta_v_node(i)) / step, 0.0, 1.0)};
}

Cell AngularGrid::phi_v_cell(double phi_v) const {
  const double step = 360.0 / n_phi_v;
  const double p = wrap360(phi_v);
  int i = std::clamp(int(std::floor(p / step)), 0, n_phi_v - 1);
  return {i, (i + 1) % n_phi_v, std::clamp((p - i * step) / step, 0.0, 1.0)};
}

double relative_light_azimuth(double phi_i, double phi_v) { return wrap360(phi_i - phi_v - 90.0); }

OnionAngles to_onion(const Direction& light, double phi_v) {
  const double p = relative_light_azimuth(light.phi, phi_v) * kDeg, t = light.theta * kDeg;
  const double x = std::cos(p) * std::sin(t), y = std::sin(p) * std::sin(t);
  const double beta = asin_deg(x);
  const double cb = std::cos(beta * kDeg);
  const double alpha = cb > 0 ? asin_deg(y / cb) : 0.0;
  return {alpha, beta};
}

Direction from_onion(const OnionAngles& a, double phi_v) {
  const double al = a.alpha * kDeg, be = a.beta * kDeg;
  const Vec3 v{std::sin(be), std::sin(al) * std::cos(be), std::cos(al) * std::cos(be)};
  Direction d = to_direction(v);
  if (d.theta > 1e-12) d.phi = wrap360(d.phi + phi_v + 90.0);
  else d.phi = 0;
  return d;
}

}  // namespace btfvq
