#pragma once
// What every competitor of the rate-distortion bench hands back: the BTF decoded at the measured
// directions of its input and the honest size of what the method stores. These baselines belong to
// the bench, not to the product.
#include <cstdint>
#include <functional>
#include <string>

#include "pipeline/btf.h"

namespace btfvq::baselines {

// Bytes stored beside every 8-bit quantized vector: its range [lo, hi] as two float32 values.
constexpr uint64_t kRangeBytes = 8;

struct BaselinePoint {
  std::string method;      // e.g. "per-view PCA"
  std::string setting;     // e.g. "C=5"
  int size = 0;            // the size parameter (components, code-book entries)
  MeasuredSample decoded;  // at the measured directions of the input
  uint64_t bytes = 0;      // every stored byte: quantized factors, their ranges, indices
  double seconds = 0;      // encode time: shared decomposition plus this size's quantization
};

// Receives one point per size; the decoded sample may be moved out (points can be large).
using PointSink = std::function<void(BaselinePoint&)>;

}  // namespace btfvq::baselines
