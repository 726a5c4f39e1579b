#pragma once
// A material compressed alone into a new database, as `btfvq compress` writes it, and what the file
// measures: its bytes and the MSSIM of its reconstruction against the sample. The rate-distortion
// tests compare settings by these two numbers.
#include <cstdint>

#include "pipeline/btf.h"
#include "pipeline/util/config.h"

namespace btfvq::test {

struct Measured {
  uint64_t bytes = 0;
  double mssim = 0;
};
Measured compress_and_measure(const MeasuredSample& sample, const ParameterDictionary& config);

}  // namespace btfvq::test
