#pragma once
// Synthetic BTFs (DESIGN.md section 6): a height-field material with albedo, roughness and (for
// grained or fibrous presets) an anisotropy direction, generated from a seed, rendered at the 81 Bonn
// view and light directions with parallax, masking, self-shadowing, a Lambertian and an anisotropic
// GGX microfacet term. The presets span easy (tile, foil) to hard (wool, corduroy) materials because
// the compression ratio depends on how much a material varies.
#include <cstdint>
#include <string>
#include <vector>

#include "pipeline/btf.h"
#include "pipeline/io/sample_io.h"

namespace btfvq {

// Floats per texel in MaterialMaps::texels (layout documented in kernels/synthetic.cl).
constexpr int kMaterialStride = 16;

// Per-texel maps of a height-field material; tileable (every map wraps around).
struct MaterialMaps {
  int width = 0, height = 0;
  float height_max = 0;  // upper bound of the height map, in texel units
  float exposure = 1;    // radiance scale before tone mapping, chosen per preset so LDR rarely clips
  // Record per texel: height, normal xyz, albedo rgb, F0 rgb, alpha along, alpha across, tangent (cos, sin), 2 spare.
  std::vector<float> texels;

  float at(int x, int y, int channel) const { return texels[(size_t(y) * width + x) * kMaterialStride + channel]; }
};

struct SyntheticPreset {
  std::string name;
  std::string description;  // one line
};

// The presets, ordered from the easiest to the hardest material.
const std::vector<SyntheticPreset>& synthetic_presets();

// Builds the maps of a preset, deterministically from `seed` (same seed, same bytes on every
// platform: own PRNG and noise, no std distributions). Throws InputError for an unknown preset
// (listing the presets) or a size outside 1..2048.
MaterialMaps make_material(const std::string& preset, int size, uint64_t seed);

// Which implementation renders: Auto follows ComputeDevice::get().backend().
enum class RenderPath { Auto, OpenCL, Reference };

// Renders the maps at the Bonn 81 x 81 directions. LDR: 8-bit sRGB-encoded codes of exposure *
// radiance; HDR: exposure * radiance as linear float. `progress` gets (texels done, texels).
MeasuredSample render_material(const MaterialMaps& maps, Dynamic dynamic, RenderPath path = RenderPath::Auto,
                               const ProgressFn& progress = {});

struct SynthOptions {
  std::string preset = "leather";
  int size = 256;
  uint64_t seed = 1;
  Dynamic dynamic = Dynamic::LDR;
  RenderPath path = RenderPath::Auto;
  ProgressFn progress;
};

// make_material + render_material.
MeasuredSample synthesize(const SynthOptions& options);

// Mean over texels of the variance of a texel's luminance (Rec. 709 weights of the stored values)
// over all direction pairs: how much the appearance of one point changes with the directions.
double mean_angular_variance(const MeasuredSample& sample);

}  // namespace btfvq
