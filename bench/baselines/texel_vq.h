#pragma once
// One-level VQ (paper 000 Sec. 4.2 and 7: "at most 1:80"): the same parametrization as btfvq (texels
// resampled onto the (phi_v, theta_v, alpha, beta) grid in the coding space, pipeline/encode/resample.h)
// with a single code-book of whole resampled texels, trained by k-means (Lloyd, deterministic
// initialization from evenly spaced training texels), and decoded back at the measured directions
// with the interpolation of btfvq's decoder. Stored: N code-vectors of 3 x grid samples values, 8-bit
// with one range per code-vector and channel, and one index of ceil(log2 N) bits per texel.
#include <vector>

#include "bench/baselines/baseline.h"
#include "pipeline/btf.h"
#include <btfvq/colour.h>
#include "pipeline/util/config.h"
#include "pipeline/parametrization.h"

namespace btfvq::baselines {

struct TexelVqOptions {
  size_t training_texels = 2048;  // k-means runs on at most this many evenly spaced texels
  int iterations = 8;             // Lloyd iterations
};

// Bytes stored for a code-book of `entries` vectors of `samples` values per channel and the index
// map of `texels` texels.
uint64_t texel_vq_bytes(size_t texels, size_t samples, int entries);

// Resamples `sample` (LDR; else InputError) with the grid and resample settings of `config` (a
// pipeline configuration) and hands `sink` one point per code-book size in `entries` (each >= 1).
void texel_vq(const MeasuredSample& sample, const ParameterDictionary& config, const std::vector<int>& entries,
              const PointSink& sink, const TexelVqOptions& options = {});

}  // namespace btfvq::baselines
