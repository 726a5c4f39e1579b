#pragma once
// Per-colour-channel PCA in CIELab (Guthe, Mueller, Schneider, Klein 2009, seed 003 Sec. 5.1, without
// the perceptual CSF filter): the BTF is written as three matrices A_L, A_a, A_b of texels x (all
// view-light pairs), each factorized on its own (no centring, a full-matrix factorization), and k
// components in total are chosen greedily: the next component is the one with the largest sigma over
// the three channels. Stored per component, 8-bit with its own range (the paper scales to [-0.5,
// 0.5] and folds the inverse into sigma; a range is the same information): the eigen-image (texels)
// and the eigen-ABRDF (pairs).
#include <array>
#include <vector>

#include "bench/baselines/baseline.h"
#include "pipeline/btf.h"
#include "pipeline/metrics/metrics.h"

namespace btfvq::baselines {

// Bytes stored for k components of `texels` texels and `pairs` direction pairs, plus one byte per
// channel for its component count.
uint64_t lab_pca_bytes(size_t texels, size_t pairs, int components);

// The greedy choice: how many of the largest components of each channel (sigmas sorted descending)
// the k largest overall are.
std::array<int, 3> greedy_split(const std::array<std::vector<float>, 3>& sigmas, int k);

// The inverse of metrics.h's srgb_to_lab: gamma-encoded sRGB on 0..255, not clamped.
Rgb lab_to_srgb(const CieLab& lab);

// Decomposes `sample` (LDR; else InputError) once and hands `sink` one point per entry of
// `components` (total components over the three channels, each >= 1).
void lab_pca(const MeasuredSample& sample, const std::vector<int>& components, const PointSink& sink);

}  // namespace btfvq::baselines
