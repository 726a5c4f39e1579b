#pragma once
// Grouped PCA (Sotnychenko 2015, seed 002 Sec. 4.3 and Table 7.1: k = 3 neighbouring views, C = 8
// components): the views are split into groups of k neighbours; per group the matrix A of texels x
// (k views x lights x RGB) is centred per row (each texel's own mean over the group's columns,
// stored as the first column of L = [m | U Sigma]) and factorized as A ~= L R with R = [1; V^T].
// Stored per group, every vector 8-bit with its own range: the mean column m, C weight columns
// (texels each) and C rows of V^T (k x lights x 3 each).
#include <vector>

#include "bench/baselines/baseline.h"
#include "pipeline/btf.h"

namespace btfvq::baselines {

// Neighbouring views: runs of k consecutive views in the sample's order (the Bonn list is ordered
// by rings of theta and by phi within a ring, so a run is an arc of one ring or the join of two).
std::vector<std::vector<size_t>> view_groups(size_t views, int k);

// Bytes stored for one group of `texels` texels and `values` columns.
uint64_t grouped_pca_bytes(size_t texels, size_t values, int components);

// Decomposes `sample` (LDR; else InputError) once with groups of `k` views and hands `sink` one
// point per entry of `components` (each >= 1).
void grouped_pca(const MeasuredSample& sample, int k, const std::vector<int>& components, const PointSink& sink);

}  // namespace btfvq::baselines
