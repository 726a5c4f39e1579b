#pragma once
// The parametrization's ceiling: every texel resampled onto the angular grid and evaluated back at
// the measured directions exactly as the decoder interpolates, without any quantization. No setting
// of btfvq (nor of one-level VQ on the same grid) can score better than this round trip, so a
// target above it cannot be reached; compress_to_target measures it when its first attempt misses
// (docs/encoder.md "Target"), the rate-distortion bench prints it per sample.
#include "pipeline/btf.h"
#include "pipeline/parametrization.h"
#include "pipeline/util/config.h"
#include <btfvq/colour.h>
#include <btfvq/directions.h>

namespace btfvq {

// A resampled texel (3 x grid.samples() values, [channel][AngularGrid::index], LDR coding space)
// evaluated at a (light, view) pair exactly as Decoder::evaluate_p4 interpolates: luminance cubic
// Hermite along beta and chroma linear along beta, then linear in alpha, theta_v and phi_v (wrapping).
Rgb evaluate_resampled(const float* texel, const AngularGrid& grid, const Direction& light, const Direction& view);

// Every texel of `sample` (LDR; else InputError) resampled with the grid and resample settings of
// `config` (a pipeline configuration) and decoded back at the sample's directions, rounded to 8 bits
// as a decoded database is. Spread over the threads of util/parallel.
MeasuredSample parametrization_roundtrip(const MeasuredSample& sample, const ParameterDictionary& config);

}  // namespace btfvq
