// `btfvq synth`: render a synthetic BTF from a material preset and write it in the UBO2003 layout,
// so that compression can be tried on materials of known, graded variability.
#include <chrono>
#include <iostream>
#include <memory>
#include <string>

#include "client/cli.h"
#include <btfvq/error.h>
#include "pipeline/io/sample_io.h"
#include "pipeline/io/synthetic.h"

namespace btfvq::cli {
namespace {

std::string preset_list() {
  std::string s;
  for (const auto& p : synthetic_presets()) s += "\n  " + p.name + ": " + p.description;
  return s;
}

uint64_t parse_seed(const Args& args) {
  const std::string text = args.get_or("seed", "1");
  size_t used = 0;
  uint64_t seed = 0;
  try {
    seed = std::stoull(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != text.size() || text[0] == '-')
    throw InputError("--seed must be a non-negative integer (got '" + text + "')");
  return seed;
}

// Prints "<stage>: NN%" to stderr each time another tenth is done.
ProgressFn progress_lines(const std::string& stage) {
  auto last = std::make_shared<int>(-1);
  return [stage, last](size_t done, size_t total) {
    const int tenth = total ? int(10 * done / total) : 10;
    if (tenth == *last) return;
    *last = tenth;
    std::cerr << stage << ": " << 10 * tenth << "%\n";
  };
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

int run_synth(const Args& args) {
  const auto preset = args.get("preset");
  if (!preset) throw InputError("missing --preset; presets:" + preset_list());
  bool known = false;
  for (const auto& p : synthetic_presets()) known = known || p.name == *preset;
  if (!known) throw InputError("unknown preset '" + *preset + "'; presets:" + preset_list());
  const std::string out = args.require("out");

  SynthOptions options;
  options.preset = *preset;
  options.size = args.integer("size", 256, 1, 2048);
  options.seed = parse_seed(args);
  options.dynamic = args.has("hdr") ? Dynamic::HDR : Dynamic::LDR;
  options.progress = progress_lines("render");
  WriteOptions write;
  write.jpeg_quality = args.integer("quality", 95, 1, 100);
  write.progress = progress_lines("write");

  std::cerr << "render: " << options.preset << " " << options.size << "x" << options.size << ", seed " << options.seed
            << (options.dynamic == Dynamic::HDR ? ", HDR" : ", LDR") << ", 81 x 81 directions\n";
  auto t0 = std::chrono::steady_clock::now();
  const MeasuredSample sample = synthesize(options);
  std::cerr << "render: done in " << seconds_since(t0) << " s\n";
  t0 = std::chrono::steady_clock::now();
  write_sample(sample, out, write);
  std::cerr << "write: done in " << seconds_since(t0) << " s\n";
  std::cout << out << "\n";
  return 0;
}

CommandRegistrar reg({"synth",
                      "synth --preset NAME [--size N] [--seed S] --out PATH(.zip|dir) [--hdr] [--quality Q]",
                      "render a synthetic BTF (presets tile, foil, wood, leather, fabric, corduroy, wool) at the 81 x 81 "
                      "Bonn directions and write it in the UBO2003 layout",
                      {{"preset", "NAME", "the material preset, one of those named above"},
                       {"size", "N", "width and height in texels, 1 to 2048 (default 256)"},
                       {"seed", "S", "the random seed, a non-negative integer (default 1)"},
                       {"out", "PATH", "where to write: a .zip or a folder"},
                       {"quality", "Q", "JPEG quality, 1 to 100 (default 95)"}},
                      {{"hdr", "", "linear float (EXR) images instead of 8-bit sRGB"}},
                      run_synth});

}  // namespace
}  // namespace btfvq::cli
