// Synthetic BTF generator: per-preset statistics (angular variance, clipping, mean) and render
// time, and the OpenCL render against the C++ reference on the same work in the same run.
#include <sstream>

#include "bench/bench_common.h"
#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/io/synthetic.h"

using namespace btfvq;

int main(int argc, char** argv) {
  const auto args = bench::parse_args(argc, argv);
  const int size = args.quick ? 32 : 128;
  std::ostringstream md;
  nlohmann::json figures;
  md << "Presets of `btfvq synth` at " << size << " x " << size
     << ", seed 1, LDR, rendered at the 81 x 81 Bonn directions on " << ComputeDevice::get().description()
     << ". Angular variance: mean over texels of the variance of luminance over all 6561 pairs (8-bit units^2).\n\n"
     << "| preset | description | angular variance | mean value | clipped at 255 | render s |\n|---|---|---|---|---|---|\n";
  for (const auto& p : synthetic_presets()) {
    const auto maps = make_material(p.name, size, 1);
    bench::Stopwatch sw;
    const auto s = render_material(maps, Dynamic::LDR, RenderPath::Auto);
    const double secs = sw.seconds();
    size_t clipped = 0;
    double sum = 0;
    for (uint8_t v : s.ldr_data()) {
      clipped += v == 255;
      sum += v;
    }
    const double n = double(s.ldr_data().size()), variance = mean_angular_variance(s);
    char row[512];
    std::snprintf(row, sizeof row, "| %s | %s | %.0f | %.1f | %.2f%% | %.1f |\n", p.name.c_str(), p.description.c_str(),
                  variance, sum / n, 100.0 * double(clipped) / n, secs);
    md << row;
    figures[p.name] = {{"angular_variance", variance}, {"mean", sum / n}, {"render_s", secs}};
  }
  // Same work on both paths: a 32 x 32 wool sample.
  const auto maps = make_material("wool", 32, 1);
  double opencl_s = 0;
  if (ComputeDevice::get().uses_opencl()) {
    render_material(maps, Dynamic::LDR, RenderPath::OpenCL);  // program build outside the timing
    bench::Stopwatch sw;
    render_material(maps, Dynamic::LDR, RenderPath::OpenCL);
    opencl_s = sw.seconds();
  }
  bench::Stopwatch sw;
  render_material(maps, Dynamic::LDR, RenderPath::Reference);
  const double reference_s = sw.seconds();
  char buf[256];
  std::snprintf(buf, sizeof buf, "\nRendering wool 32 x 32: OpenCL %.2f s, C++ reference %.2f s: **%.1fx**.\n", opencl_s,
                reference_s, opencl_s > 0 ? reference_s / opencl_s : 0.0);
  md << buf;
  figures["wool32_opencl_s"] = opencl_s;
  figures["wool32_reference_s"] = reference_s;
  bench::write_section(args, "Synthetic materials", 10, md.str(), figures);
  return 0;
}
