#pragma once
// Decoding whole images and whole BTFs from a database: the BTF at the measured directions (the
// input of evaluation, of `btfvq decode`), and single direction-pair images (previews).
//
// Every texel of a material is (P4 entry) x (P6 scale), so an image costs one decode per distinct
// P4 entry plus one multiply per texel, instead of one full chained decode per texel.
#include <string>
#include <vector>

#include "pipeline/btf.h"
#include "pipeline/codebook.h"
#include <btfvq/directions.h>

namespace btfvq {

// RGB of every texel of `material` for one (light, view) pair, row-major, 3 floats per texel,
// gamma-encoded 0..255 for LDR (not clamped), linear for HDR.
std::vector<float> decode_image(const Database& db, const std::string& material, const Direction& light,
                                const Direction& view);

// The material decoded at every (view, light) pair of `geometry` (its views and per-view lights; its
// values are ignored): an LDR material gives 8-bit values rounded and clamped to 0..255, an HDR one
// linear floats. Uses `threads` threads over the pairs.
MeasuredSample reconstruct_sample(const Database& db, const std::string& material, const MeasuredSample& geometry,
                                  int threads = 2);
// The same at the 81 x 81 Bonn directions.
MeasuredSample reconstruct_bonn(const Database& db, const std::string& material, int threads = 2);

}  // namespace btfvq
