#pragma once
// Per-view PCA (Sattler, Sarlette, Klein 2003; the "PCA" column of paper 000 Sec. 7, five components
// per view): for every view direction the texels' vectors of (light, RGB) values are centred on their
// mean and approximated by their C principal components. Stored per view: C eigen-ABRDFs of
// lights x 3 values, C weights per texel, the mean vector, every one 8-bit with its own range.
#include <vector>

#include "bench/baselines/baseline.h"
#include "pipeline/btf.h"

namespace btfvq::baselines {

// Bytes stored for one view of `texels` texels and `values` = lights x 3 values per texel.
uint64_t per_view_pca_bytes(size_t texels, size_t values, int components);

// Decomposes `sample` (LDR; else InputError) once and hands `sink` one point per entry of
// `components` (each >= 1). Texel-vector PCA, so C = lights x 3 reconstructs up to quantization.
void per_view_pca(const MeasuredSample& sample, const std::vector<int>& components, const PointSink& sink);

}  // namespace btfvq::baselines
