// probe_ceiling SAMPLE [CONFIG]: the parametrization's ceiling of a measured sample -- every texel
// resampled to the grid of configs/pipeline.json (with CONFIG's keys on top, e.g. another "grid") and
// decoded back at the measured directions, no quantization -- scored as `btfvq eval` scores a database
// (MSSIM of Y, PSNR, CIEDE2000). No encoder setting can beat it; the rate-distortion bench prints the
// same figure per sample.
#include <cstdio>

#include <btfvq/error.h>
#include "pipeline/encode/ceiling.h"
#include "pipeline/io/sample_io.h"
#include "pipeline/metrics/metrics.h"

using namespace btfvq;

int main(int argc, char** argv) {
  if (argc != 2 && argc != 3) {
    std::fprintf(stderr, "usage: probe_ceiling SAMPLE [CONFIG]\n");
    return 2;
  }
  try {
    const MeasuredSample sample = load_sample(argv[1]);
    ParameterDictionary config = ParameterDictionary::embedded_default("pipeline");
    if (argc == 3) config.merge(ParameterDictionary::load_file(argv[2]));
    const EvaluationReport e = evaluate(sample, parametrization_roundtrip(sample, config));
    std::printf("%s\tceiling MSSIM %.4f\tPSNR %.2f dB\tCIEDE2000 %.3f\n", argv[1], e.mssim_y, e.psnr, e.ciede2000_mean);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "probe_ceiling: %s\n", e.what());
    return 1;
  }
}
