// probe_ceiling SAMPLE [CONFIG]: the parametrization's ceiling of a measured sample -- every texel
// resampled to the grid of configs/pipeline.json (with CONFIG's keys on top, e.g. another "grid") and
// decoded back at the measured directions, no quantization -- scored as `btfvq eval` scores a database
// (MSSIM of Y, PSNR, CIEDE2000). No encoder setting can beat it; the rate-distortion bench prints the
// same figure per sample.
#include <cstdio>

#include <btfvq/error.h>
#include "pipeline/encode/ceiling.h"
#include "pipeline/encode/compress.h"
#include "pipeline/io/sample_io.h"
#include "pipeline/metrics/metrics.h"
#include "pipeline/util/config.h"

using namespace btfvq;

int main(int argc, char** argv) {
  if (argc != 2 && argc != 3) {
    std::fprintf(stderr, "usage: probe_ceiling SAMPLE [CONFIG]\n");
    return 2;
  }
  try {
    // The one check of user settings (compress's): a misspelled grid key must not measure the shipped grid.
    const ParameterDictionary config =
        argc == 3 ? pipeline_config(ParameterDictionary::load_file(argv[2]).json(), argv[2])
                  : ParameterDictionary::embedded_default("pipeline");
    const MeasuredSample sample = load_sample(argv[1]);
    const EvaluationReport e = evaluate(sample, parametrization_roundtrip(sample, config));
    std::printf("%s\tceiling MSSIM %.4f\tPSNR %.2f dB\tCIEDE2000 %.3f\n", argv[1], e.mssim_y, e.psnr, e.ciede2000_mean);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "probe_ceiling: %s\n", e.what());
    return 1;
  }
}
