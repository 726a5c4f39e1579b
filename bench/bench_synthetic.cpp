// Synthetic BTF generator: per-preset statistics (angular variance, clipping, mean) and render time.
//   bench_synthetic [size=32] [preset|all] [reference]
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "pipeline/opencl_runtime.h"
#include "pipeline/synthetic.h"

using namespace btfvq;

int main(int argc, char** argv) {
  const int size = argc > 1 ? std::atoi(argv[1]) : 32;
  const std::string which = argc > 2 ? argv[2] : "all";
  const RenderPath path = argc > 3 && std::string(argv[3]) == "reference" ? RenderPath::Reference : RenderPath::Auto;
  std::printf("device: %s\n", ComputeDevice::get().description().c_str());
  std::printf("%-9s %8s %8s %8s %8s %8s %9s\n", "preset", "hmax", "variance", "mean", "clip%", "zero%", "render_s");
  for (const auto& p : synthetic_presets()) {
    if (which != "all" && which != p.name) continue;
    const auto maps = make_material(p.name, size, 1);
    const auto t0 = std::chrono::steady_clock::now();
    const auto s = render_material(maps, Dynamic::LDR, path);
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    size_t clipped = 0, zero = 0;
    double sum = 0;
    for (uint8_t v : s.ldr_data()) {
      clipped += v == 255;
      zero += v == 0;
      sum += v;
    }
    const double n = double(s.ldr_data().size());
    std::printf("%-9s %8.2f %8.1f %8.1f %8.3f %8.3f %9.2f\n", p.name.c_str(), maps.height_max,
                mean_angular_variance(s), sum / n, 100 * clipped / n, 100 * zero / n, secs);
  }
  return 0;
}
