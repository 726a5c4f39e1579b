// `btfvq info PATH`: what a file holds, without decoding it. Samples (a directory or a zip of
// UBO2003 images) today; databases (files that start with the .btfdb magic) are to be added here as
// one more branch before the sample check.
#include <iostream>
#include <ostream>
#include <string>

#include "client/cli.h"
#include "pipeline/error.h"
#include "pipeline/sample_io.h"

namespace btfvq::cli {
namespace {

std::string with_thousands(uint64_t n) {
  std::string digits = std::to_string(n), out;
  for (size_t i = 0; i < digits.size(); ++i) {
    if (i > 0 && (digits.size() - i) % 3 == 0) out += ',';
    out += digits[i];
  }
  return out;
}

void print_sample_info(std::ostream& out, const std::string& path, const SampleInfo& info) {
  out << "sample:     " << path << "\n";
  out << "size:       " << info.width << " x " << info.height << "\n";
  out << "directions: " << info.views << " views x ";
  if (info.min_lights_per_view == info.lights_per_view)
    out << info.lights_per_view << " lights\n";
  else
    out << info.min_lights_per_view << " to " << info.lights_per_view << " lights per view\n";
  out << "dynamic:    " << (info.dynamic == Dynamic::HDR ? "HDR (linear float)" : "LDR (8-bit sRGB-encoded)") << "\n";
  out << "images:     " << info.images << "\n";
  out << "raw bytes:  " << with_thousands(info.raw_bytes) << "\n";
}

int run_info(const Args& args) {
  if (args.positional.size() != 1) throw InputError("usage: btfvq info PATH");
  const std::string& path = args.positional[0];
  if (is_sample_path(path)) {
    print_sample_info(std::cout, path, inspect_sample(path));
    return 0;
  }
  throw InputError(path + " is not a BTF sample (a directory or zip of UBO2003 images)");
}

CommandRegistrar reg({"info", "info PATH", "describe a sample (directory or zip): size, directions, LDR/HDR, raw bytes",
                      {}, {}, run_info});

}  // namespace
}  // namespace btfvq::cli
