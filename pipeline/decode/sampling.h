#pragma once
// Importance sampling of the light direction for a given view (paper Sec. 5.2), straight from the
// P2/P1 code-books: inverse transform over the [alpha, beta] onion slices of the luminance, alpha by
// a marginal CDF, then beta by the conditional CDF inside the chosen alpha.
//
// The density (exact definition and derivation in docs/sampling.md): in the coordinates
// (alpha in radians, s = sin(beta)) the onion map is area-preserving, d omega = d alpha ds, and the
// beta nodes are uniform in s. The sampled density is the bilinear interpolation over that uniform
// (alpha, s) grid of the node luminances of the texel for the view (the decoder's P4/P3 blend over
// phi_v and theta_v, the luminance of each M entry's RGB), plus a floor of kSamplingFloor x their
// mean and kSamplingColumnFloor x the mean of the node's alpha column, normalised over the
// hemisphere. At every grid node the pdf is therefore proportional to the luminance the decoder
// evaluates there (+ the floors); between nodes it is the bilinear blend of
// the same values. Because the density is positive everywhere and its CDFs are continuous and
// strictly increasing, nearby (xi1, xi2) give nearby directions (the continuity property of Sec. 5.2).
//
// Directions are unit vectors in the material's tangent frame: z along the normal, x the tangent
// (azimuth phi = 0), y the bitangent (phi = 90 degrees) -- the frame of Direction/to_vector.
#include <cstddef>
#include <cstdint>
#include <vector>

#include "pipeline/decode/decoder.h"
#include <btfvq/directions.h>

namespace btfvq {

// The floor added to every node of the sampling density, relative to the mean node luminance: keeps
// the density positive (continuity; no direction with reflectance is ever unsampleable).
inline constexpr double kSamplingFloor = 0.01;
// A second floor per alpha column, relative to that column's mean luminance over s: bounds how
// steep the conditional inverse CDF can get beside a bright peak (high dynamic range), so that
// sampling stays continuous with a moderate slope everywhere.
inline constexpr double kSamplingColumnFloor = 0.01;

struct LightSample {
  Vec3 direction;   // unit vector, z >= 0
  double pdf = 0;   // with respect to solid angle (1/sr)
};

// Luminance of a decoded value, the quantity sampling follows: BT.601 luma of the gamma-encoded RGB
// for LDR (= (Y - 16) x 255/219 of the coding space), Rec. 709 luminance of linear RGB for HDR.
double sampling_luminance(const Rgb& rgb, bool hdr);

class LightSampler {
 public:
  // Precomputes, per P2 entry, the luminance at the (alpha, beta) nodes and its integrals along
  // beta, and per P4 entry the P2 entries and scales of its view nodes (so a sample reads 4 P2
  // rows and blends them). Keeps a reference to `decoder` (and through
  // it to the database): both must outlive the sampler. Thread-safe after construction.
  explicit LightSampler(const Decoder& decoder);

  // A light direction for `view` at texel (x, y) (wrapped modulo the material size) from two
  // numbers in [0, 1] (clamped). Where the reflectance is zero for every light (view below the
  // horizon, texel not compressed) the sample is uniform over the hemisphere. Throws NotFoundError
  // for a material index past the end.
  LightSample sample(size_t material, int x, int y, const Vec3& view, double xi1, double xi2) const;
  // The density sample() draws `light` with (0 below the horizon).
  double pdf(size_t material, int x, int y, const Vec3& light, const Vec3& view) const;

  const Decoder& decoder() const { return decoder_; }

 private:
  struct Mixture;  // the up to four weighted P2 entries of one (texel, view)
  Mixture mixture(size_t material, int x, int y, const Vec3& view) const;
  double normaliser(const Mixture& mx) const;
  const float* nodes(uint32_t p2, bool hdr) const;
  const float* rows(uint32_t p2, bool hdr) const;

  const Decoder& decoder_;
  int na_, nb_, nt_, np_;
  // Per P4 entry and view node (phi_v, theta_v): the P2 entry its chain P4 -> P3 -> M reaches and
  // the product of the P4 and P3 scales, so a query skips two dependent look-ups.
  struct ViewNode {
    uint32_t p2;
    float scale;
  };
  std::vector<ViewNode> view_nodes_;
  double d_alpha_, d_s_;  // grid steps in radians and in sin(beta)
  // Per dynamic range (0 LDR, 1 HDR; built only if a material uses it), per P2 entry:
  // n_alpha x n_beta node luminances, n_alpha beta-integrals, the mean node luminance, the total.
  std::vector<float> node_lum_[2];
  std::vector<float> row_int_[2];
  std::vector<float> mean_lum_[2];
  std::vector<double> total_[2];  // integral of the node luminance over the (alpha, s) square
};

}  // namespace btfvq
