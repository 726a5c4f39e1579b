// Throughput of RBF resampling (texels/s) on the OpenCL device and with the C++ reference path, in
// one run, for the Bonn geometry and the default grid and settings.
#include <ctime>
#include <sstream>
#include <vector>

#include "bench/bench_common.h"
#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/encode/resample.h"

using namespace btfvq;

int main(int argc, char** argv) {
  const auto args = bench::parse_args(argc, argv);
  const int passes = args.quick ? 2 : 8;
  MeasuredSample s = make_bonn_sample(64, 64, Dynamic::LDR);
  uint32_t x = 12345;
  for (auto& v : s.ldr_data()) v = uint8_t((x = x * 1664525u + 1013904223u) >> 24);
  const ResampleSettings settings = ResampleSettings::from(ParameterDictionary::embedded_default("pipeline"));

  bench::Stopwatch sw;
  const ResampleOperator op(s, AngularGrid{}, settings);
  const double build_s = sw.seconds();

  const size_t batch = 1024;
  std::vector<float> out(op.values_per_texel() * batch);
  double opencl_rate = 0;
  if (ComputeDevice::get().uses_opencl()) {
    op.apply_opencl(s, 0, batch, out.data());  // builds the program and uploads the operator
    sw.reset();
    for (int p = 0; p < passes; ++p)
      for (size_t t = 0; t < s.texel_count(); t += batch) op.apply_opencl(s, t, batch, out.data());
    opencl_rate = double(passes) * double(s.texel_count()) / sw.seconds();
  }
  sw.reset();
  op.apply_reference(s, 0, batch, out.data());
  const double reference_rate = double(batch) / sw.seconds();

  std::ostringstream md;
  char buf[1024];
  std::snprintf(buf, sizeof buf,
                "Bonn 81 x 81 LDR input onto the default 16 x 7 x 11 x 11 grid (3 channels), two-step local RBF "
                "(pipeline/encode/resample.h). Operator build: %.2f s.\n\n"
                "| path | texels/s | seconds per 256 x 256 sample |\n|---|---|---|\n"
                "| OpenCL (%s) | %.0f | %.1f |\n| C++ reference (1 thread) | %.0f | %.1f |\n\n"
                "OpenCL / reference: **%.1fx** (same work, same run).\n",
                build_s, ComputeDevice::get().description().c_str(), opencl_rate, 65536.0 / std::max(opencl_rate, 1e-9),
                reference_rate, 65536.0 / reference_rate, opencl_rate / reference_rate);
  md << buf;
  bench::write_section(args, "Resampling", 20, md.str(),
                       {{"operator_build_s", build_s}, {"opencl_texels_per_s", opencl_rate},
                        {"reference_texels_per_s", reference_rate}, {"opencl_over_reference", opencl_rate / reference_rate}});
  return 0;
}
