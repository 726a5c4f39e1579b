// Encodes a synthetic W x W material with the default pipeline config and reports texels/s per
// phase and code-book sizes. Usage: bench_encoder [W] [ssim|mse]
#include <cstdio>
#include <cstdlib>
#include <string>

#include "pipeline/config.h"
#include "pipeline/schedule.h"
#include "../tests/support/synthetic_texels.h"

using namespace btfvq;

int main(int argc, char** argv) {
  const int w = argc > 1 ? std::atoi(argv[1]) : 64;
  auto cfg = ParameterDictionary::embedded_default("pipeline");
  if (argc > 2) cfg.merge(ParameterDictionary::parse(std::string("{\"similarity\": {\"metric\": \"") + argv[2] + "\"}}", "args"));
  const SimilaritySettings sim = SimilaritySettings::from(cfg);
  const Thresholds thr = Thresholds::from(cfg, sim.metric);
  const ScheduleSettings sch = ScheduleSettings::from(cfg);
  test::SyntheticMaterial mat(w, w);
  Codebooks books(mat.grid);
  const ScheduleResult r = run_schedule(books, Dynamic::LDR, w, w, mat.source(), thr, sim, sch);
  for (int p = 0; p < 3; ++p) {
    const auto& s = r.report.sizes[p];
    std::printf("phase %d: %zu texels in %.2f s (%.1f texels/s); sizes P1 %zu C %zu I1 %zu I2 %zu P2 %zu M %zu P3 %zu P4 %zu\n",
                p + 1, r.report.texels[p], r.report.seconds[p],
                r.report.seconds[p] > 0 ? double(r.report.texels[p]) / r.report.seconds[p] : 0.0, s.p1, s.c, s.i1, s.i2,
                s.p2, s.m, s.p3, s.p4);
  }
  double mean = 0, worst = 0;
  for (float d : r.dissimilarity) {
    mean += d;
    worst = std::max(worst, double(d));
  }
  std::printf("dissimilarity mean %.4f worst %.4f; comparisons %llu pruned %llu fallbacks %llu\n",
              mean / double(r.dissimilarity.size()), worst, (unsigned long long)r.report.encoder.comparisons,
              (unsigned long long)r.report.encoder.pruned, (unsigned long long)r.report.encoder.fallbacks);
  return 0;
}
