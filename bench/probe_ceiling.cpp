// probe_ceiling SAMPLE [CONFIG]: the parametrization's ceiling of a measured sample -- every texel
// resampled to the grid of configs/pipeline.json (with CONFIG's keys on top, e.g. another "grid") and
// decoded back at the measured directions, no quantization -- scored as `btfvq eval` scores a database
// (MSSIM of Y, PSNR, CIEDE2000). No encoder setting can beat it; the rate-distortion bench prints the
// same figure per sample.
#include <cstdio>
#include <string>
#include <vector>

#include <btfvq/error.h>
#include "pipeline/encode/ceiling.h"
#include "pipeline/io/sample_io.h"
#include "pipeline/metrics/metrics.h"
#include "pipeline/util/config.h"

using namespace btfvq;

namespace {

void leaf_keys(const nlohmann::json& j, const std::string& prefix, std::vector<std::string>& out) {
  for (const auto& [k, v] : j.items()) {
    const std::string key = prefix.empty() ? k : prefix + "." + k;
    if (v.is_object()) leaf_keys(v, key, out);
    else out.push_back(key);
  }
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2 && argc != 3) {
    std::fprintf(stderr, "usage: probe_ceiling SAMPLE [CONFIG]\n");
    return 2;
  }
  try {
    ParameterDictionary config = ParameterDictionary::embedded_default("pipeline");
    if (argc == 3) {
      const ParameterDictionary overlay = ParameterDictionary::load_file(argv[2]);
      std::vector<std::string> keys;
      leaf_keys(overlay.json(), "", keys);
      for (const std::string& key : keys)  // a misspelled key must not measure the shipped grid
        if (!config.has(key)) throw ConfigError(std::string(argv[2]) + ": unknown key '" + key + "'");
      config.merge(overlay);
    }
    const MeasuredSample sample = load_sample(argv[1]);
    const EvaluationReport e = evaluate(sample, parametrization_roundtrip(sample, config));
    std::printf("%s\tceiling MSSIM %.4f\tPSNR %.2f dB\tCIEDE2000 %.3f\n", argv[1], e.mssim_y, e.psnr, e.ciede2000_mean);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "probe_ceiling: %s\n", e.what());
    return 1;
  }
}
