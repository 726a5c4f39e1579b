#pragma once
// BTF-CIELab: the perceptual difference of two whole BTFs of Guthe, Mueller, Schneider and Klein,
// "BTF-CIELab: A Perceptual Difference Measure for Quality Assessment and Compression of BTFs"
// (Computer Graphics Forum 28(1), 2009). Both samples go through the same model of seeing:
//   1. display values -> linear sRGB -> CIE XYZ -> cone responses (L, M, S) -> the l-alpha-beta
//      opponent channels of Ruderman, Cronin and Chiao (1998), on logarithmic cone responses;
//   2. the spatio-angular contrast sensitivity filter: a sum of six-dimensional Gaussians (paper
//      Table 1: three on the achromatic channel l, two on each chromatic channel alpha, beta), each
//      separable into a spatial Gaussian (applied in the frequency domain, widened along the view's
//      azimuth by 1 / cos(theta_view) for the foreshortening, paper Sec. 3.2) and two angular
//      Gaussians applied by direct convolution over the measured view and light directions (no
//      resampling); the filtered components are recombined with their weights;
//   3. back to CIELab and CIEDE2000 per texel and direction pair (the Sharma-checked ciede2000 of
//      metrics.h), pooled with weight cos(theta_view) into mean, standard deviation and RMS.
// A viewing condition (spatial resolution in texels per degree, angular speed in degrees per
// second, paper Sec. 3.4) turns the table's degrees and seconds into texels and directions.
// docs/metrics.md "BTF-CIELab" lists every choice the paper leaves open.
#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "pipeline/btf.h"

namespace btfvq {

// Paper Sec. 3.4: resolutions of 2 .. 100 texels per degree and speeds of 10 .. 1000 degrees per
// second cover the reasonable mappings; the default is the geometric centre of both ranges.
struct ViewingCondition {
  double resolution = 14.142135623730951;  // texels per degree of visual angle, sqrt(2 * 100)
  double speed = 100.0;                    // degrees per second the light or view turns, sqrt(10 * 1000)
};
// "RESOLUTION,SPEED" (either may be empty for its default), e.g. "50,100" or "30,". InputError if
// malformed or not positive (speed 0 is allowed: no angular filtering).
ViewingCondition parse_viewing_condition(const std::string& text);

enum class CsfChannel { Achromatic, Chromatic };
// One Gaussian of the filter: weight, spatial deviation sigma (degrees of visual angle) and angular
// deviation delta (seconds), in the form exp(-x^2 / sigma^2 - t^2 / delta^2) of the paper, each
// factor normalised to unit integral.
struct CsfComponent {
  CsfChannel channel;
  double weight;
  double sigma_degrees;
  double delta_seconds;
};
// The five components of paper Table 1 (achromatic 1-3, then chromatic 1-2).
const std::vector<CsfComponent>& btf_cielab_components();

// Gain of the filter of `channel` at a spatial frequency of f cycles per degree (frontal view, no
// angular variation): sum_i w_i exp(-pi^2 sigma_i^2 f^2). 1 at f = 0.
double csf_spatial_gain(CsfChannel channel, double cycles_per_degree);

// Relative solid angle of each direction's Voronoi cell on the upper hemisphere (they sum to 1):
// the quadrature weight of the angular convolution, so that dense regions of an irregular sampling
// do not count more. Independent of the order of `dirs`.
std::vector<double> solid_angle_weights(const std::vector<Direction>& dirs);

// The angular convolution of one component over a direction set: row a holds (b, weight) for every
// direction b with exp(-(angle(a, b) / width)^2) >= kAngularCutoff, weight proportional to that
// times b's solid-angle weight, normalised so the row sums to 1 (a uniform field stays uniform).
// width_degrees = delta * speed; 0 gives the identity.
inline constexpr double kAngularCutoff = 1e-3;
struct AngularKernel {
  std::vector<std::vector<std::pair<uint32_t, float>>> rows;
};
AngularKernel angular_kernel(const std::vector<Direction>& dirs, double width_degrees);

struct BtfCielabOptions {
  ViewingCondition condition;
  int threads = 2;
  // Working memory for the filtered images of one block of light directions (both samples, all
  // views, seven channels); blocks are made as large as fit, at least one light.
  size_t memory_budget = size_t(960) << 20;
};

struct BtfCielabReport {
  double mean = 0, stddev = 0, rms = 0;  // of CIEDE2000 over texels and direction pairs, weight cos(theta_view)
  ViewingCondition condition;
  double seconds = 0;           // wall time of btf_cielab()
  size_t light_blocks = 0;      // passes over the samples
  size_t working_bytes = 0;     // filtered images and filter tables held at once
  size_t pairs = 0;             // direction pairs compared
};

// Both samples must have the geometry evaluate() requires, and every view must share one light list
// (the angular convolution is separable over view and light only then); else InputError.
BtfCielabReport btf_cielab(const MeasuredSample& reference, const MeasuredSample& test, const BtfCielabOptions& options = {});

}  // namespace btfvq
