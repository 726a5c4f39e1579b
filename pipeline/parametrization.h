#pragma once
// The [alpha, beta] "onion slice" parametrization of light directions (paper Sec. 4.1) and the
// regular (theta_v, phi_v) grid of view directions, with exactly the grids, azimuth convention and
// interpolation cells of the original authors' decoder (docs/btfbase-format.md), so
// that one decoder reads their databases and ours.
//
// Grid formulas (all angles in degrees):
//   beta_k    = asin(-1 + 2k/(n_beta-1))         k = 0..n_beta-1   (uniform in sin(beta); -90, 0, 90
//                                                                    exactly at the ends and middle)
//   alpha_k   = -90 + k * 180/(n_alpha-1)        k = 0..n_alpha-1
//   theta_v_k = k * 90/(n_theta_v-1)             k = 0..n_theta_v-1 (15 deg steps for 7 nodes)
//   phi_v_k   = k * 360/n_phi_v                  k = 0..n_phi_v-1   (22.5 deg steps; wraps to 0)
// Mapping of a light direction, given the view azimuth phi_v:
//   phi' = phi_i - phi_v - 90 (mod 360); x = cos(phi') sin(theta_i); y = sin(phi') sin(theta_i)
//   beta = asin(x); alpha = asin(clamp(y / cos(beta), -1, 1))
// and back: [x, y, z] = [sin(beta), sin(alpha) cos(beta), cos(alpha) cos(beta)] (paper eq. 2).
#include <cstddef>

#include <btfvq/directions.h>

namespace btfvq {

// Light direction in onion-slice coordinates, degrees, both in [-90, 90].
struct OnionAngles {
  double alpha = 0;
  double beta = 0;
};

// Two neighbouring grid nodes and the weight of the second: value = (1-w) v[i0] + w v[i1].
struct Cell {
  int i0 = 0;
  int i1 = 0;
  double w = 0;
};

struct AngularGrid {
  int n_beta = 11;
  int n_alpha = 11;
  int n_theta_v = 7;
  int n_phi_v = 16;

  double beta_node(int k) const;
  double alpha_node(int k) const;
  double theta_v_node(int k) const;
  double phi_v_node(int k) const;

  Cell beta_cell(double beta) const;
  Cell alpha_cell(double alpha) const;
  Cell theta_v_cell(double theta_v) const;  // at or beyond the last node only that node is used
  Cell phi_v_cell(double phi_v) const;      // wraps: the node after the last is node 0

  // Samples of one channel of a resampled texel F_x.
  size_t slice1() const { return size_t(n_beta); }
  size_t slice2() const { return slice1() * size_t(n_alpha); }
  size_t slice3() const { return slice2() * size_t(n_theta_v); }
  size_t samples() const { return slice3() * size_t(n_phi_v); }
  // Position of a sample inside one channel: [phi_v][theta_v][alpha][beta], beta fastest, so that
  // 1D, 2D and 3D slices are contiguous runs.
  size_t index(int phi_v, int theta_v, int alpha, int beta) const {
    return ((size_t(phi_v) * size_t(n_theta_v) + size_t(theta_v)) * size_t(n_alpha) + size_t(alpha)) * size_t(n_beta) +
           size_t(beta);
  }

  bool operator==(const AngularGrid& o) const {
    return n_beta == o.n_beta && n_alpha == o.n_alpha && n_theta_v == o.n_theta_v && n_phi_v == o.n_phi_v;
  }
  // Throws InputError unless every count is usable (beta, alpha >= 3 and odd-free; theta_v >= 2; phi_v >= 1).
  void validate() const;
};

// Azimuth of the light relative to the view as the original decoder defines it: phi_i - phi_v - 90.
double relative_light_azimuth(double phi_i, double phi_v);

// Light direction -> onion-slice angles for a view with azimuth phi_v.
OnionAngles to_onion(const Direction& light, double phi_v);
// Onion-slice angles -> light direction (theta, phi in [0, 360)) for a view with azimuth phi_v.
Direction from_onion(const OnionAngles& a, double phi_v);

}  // namespace btfvq
