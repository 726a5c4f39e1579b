// Throughput of RBF resampling (texels/s) on the OpenCL device and with the C++ reference, for the
// Bonn geometry and the default grid and settings. A 64 x 64 random LDR sample is resampled
// `passes` times (default 16 = as many texels as a 256 x 256 sample) through a reused buffer.
//   bench_resample [passes]
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <vector>

#include "pipeline/opencl_runtime.h"
#include "pipeline/resample.h"

using namespace btfvq;

int main(int argc, char** argv) {
  const int passes = argc > 1 ? std::atoi(argv[1]) : 16;
  MeasuredSample s = make_bonn_sample(64, 64, Dynamic::LDR);
  uint32_t x = 12345;
  for (auto& v : s.ldr_data()) v = uint8_t((x = x * 1664525u + 1013904223u) >> 24);
  const ResampleSettings settings = ResampleSettings::from(ParameterDictionary::embedded_default("pipeline"));
  using clock = std::chrono::steady_clock;
  auto seconds = [](clock::time_point a, clock::time_point b) { return std::chrono::duration<double>(b - a).count(); };

  const auto t0 = clock::now();
  const ResampleOperator op(s, AngularGrid{}, settings);
  const auto t1 = clock::now();
  std::printf("operator build: %.3f s\n", seconds(t0, t1));

  const size_t batch = 1024;
  std::vector<float> out(op.values_per_texel() * batch);
  if (ComputeDevice::get().uses_opencl()) {
    op.apply_opencl(s, 0, batch, out.data());  // builds the program and uploads the operator
    const auto a = clock::now();
    const std::clock_t ca = std::clock();
    for (int p = 0; p < passes; ++p)
      for (size_t t = 0; t < s.texel_count(); t += batch) op.apply_opencl(s, t, batch, out.data());
    const auto b = clock::now();
    const double cpu = double(std::clock() - ca) / CLOCKS_PER_SEC;
    const double n = double(passes) * double(s.texel_count());
    std::printf("OpenCL (%s): %.0f texels/s, %.1f s per 256x256 sample\n", ComputeDevice::get().description().c_str(),
                n / seconds(a, b), 65536.0 / (n / seconds(a, b)));
    // The machine may be shared: process CPU time (all PoCL threads) says what the kernels cost.
    std::printf("OpenCL: %.0f texels per CPU-second\n", n / cpu);
  }
  const auto a = clock::now();
  const std::clock_t ca = std::clock();
  op.apply_reference(s, 0, batch, out.data());
  const auto b = clock::now();
  const double cpu = double(std::clock() - ca) / CLOCKS_PER_SEC;
  std::printf("C++ reference (1 thread): %.0f texels/s, %.0f texels per CPU-second\n", double(batch) / seconds(a, b),
              double(batch) / cpu);
  return 0;
}
