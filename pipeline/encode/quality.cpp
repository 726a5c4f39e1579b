#include "pipeline/encode/quality.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <btfvq/error.h>
#include "pipeline/util/config.h"

namespace btfvq {

namespace {

// Every dissimilarity bound of the shipped settings times this factor: 3 at Q = 0, 1 at the
// default Q = 50, 1/3 at Q = 100. Geometric, because the bytes follow the thresholds roughly as a
// power law (docs/encoder.md "Quality"), so equal steps of Q are about equal ratios of size.
double threshold_factor(double q) { return std::pow(3.0, (kDefaultQuality - q) / 50.0); }

// Above kGrowthQuality the share of texels that grow the code-books rises too (docs/encoder.md
// "Quality"). Phase 3 composes P4 entries only from frozen P3 entries, so a material whose texels
// share little (wool) gains quality only by growing more of them: wool 64 gives MSSIM 0.50 with
// the shipped 6 % grown, 0.60 with 25 %, 0.81 (its ceiling 0.836) with every texel. On a material
// that shares (leather) growth buys MSSIM at far more bytes and time than the thresholds do:
// leather 128 reached 0.90 at 1:361 with thresholds alone but at 1:163 when the grown share rose
// from Q 50 on. So the thresholds carry the scale up to kGrowthQuality, and growth the last steps
// to Q 100, where every texel grows. growth(): 0 at and below kGrowthQuality, 1 at Q = 100.
double growth(double q) { return std::max(0.0, (q - kGrowthQuality) / (100.0 - kGrowthQuality)); }

}  // namespace

nlohmann::json quality_settings(double q) {
  if (!(q >= 0 && q <= 100)) throw InputError("quality must be a number from 0 to 100, got " + std::to_string(q));
  const nlohmann::json shipped = ParameterDictionary::embedded_default("pipeline").json();
  const double f = threshold_factor(q);
  nlohmann::json out;
  // SSIM dissimilarities live in [0, 2]; the leaf bounds p1 and i1 saturate below that, where
  // every row matches anyway.
  for (const auto& [key, value] : shipped["thresholds"]["ssim"].items()) {
    const double cap = key == "c" ? 1e6 : key == "p1" || key == "i1" ? 0.95 : 2.0;
    out["thresholds"]["ssim"][key] = std::min(cap, value.get<double>() * f);
  }
  // The MSE thresholds (the growing phases' with similarity.metric "mse"; with the shipped
  // schedule.assign_metric they bound the groups compose_p3 rebuilds) follow the same factor.
  for (const auto& [key, value] : shipped["thresholds"]["mse"].items())
    out["thresholds"]["mse"][key] = value.get<double>() * f;
  // Growth, geometric in the shares: phase 1 three times the shipped share at Q 100, phase 2 every
  // texel phase 1 leaves; phase 2 relaxes its thresholds less (shipped 2.5 down to 1.5).
  const nlohmann::json& schedule = shipped["schedule"];
  const double g = growth(q);
  const double p1 = schedule["phase1_fraction"].get<double>() * std::pow(3.0, g);
  const double p2 = schedule["phase2_fraction"].get<double>();
  out["schedule"]["phase1_fraction"] = p1;
  out["schedule"]["phase2_fraction"] = std::min(1.0 - p1, p2 * std::pow((1.0 - p1) / p2, g));
  out["schedule"]["relax_factor"] = schedule["relax_factor"].get<double>() * (1 - g) + 1.5 * g;
  // Composition: from texels this much farther than the P4 bound, when it gains this much (in the
  // units of schedule.assign_metric; an SSIM dissimilarity is at most 2).
  const double most = schedule["assign_metric"] == "ssim" ? 2.0 : 1e6;
  out["schedule"]["compose_threshold"] = std::min(most, schedule["compose_threshold"].get<double>() * f);
  out["schedule"]["compose_gain"] = schedule["compose_gain"].get<double>() * f;
  // Above kGrowthQuality phase 3 may also compose new P3 entries of stored M entries: on leather 64
  // it bought more quality per byte than growth (Q 90 with it 0.939 at 1:90, Q 95 without it 0.930
  // at 1:40, Q 95 with it 0.961 at 1:30; docs/encoder.md "Quality").
  out["schedule"]["compose_p3"] = q > kGrowthQuality;
  // Switched on for every texel at once it was a step (wool 32 on 24 azimuths: Q 90 0.586, Q 90.5
  // 0.911 at 3x the bytes) that no target between could land on. So the share of phase-3 texels that
  // may compose them rises linearly from none just above kGrowthQuality to all at kComposeQuality.
  // (A rising bound on the groups' dissimilarity instead kept the step, only narrower: wool's groups
  // miss by much the same, so 0.63 at Q 91 and 0.90 at Q 91.5.)
  out["schedule"]["compose_p3_share"] =
      q > kGrowthQuality ? std::min(1.0, (q - kGrowthQuality) / (kComposeQuality - kGrowthQuality))
                         : schedule["compose_p3_share"].get<double>();
  // The share of the material's error the refinement's merges may add: a higher quality merges less.
  out["refine"]["merge_budget"] = shipped["refine"]["merge_budget"].get<double>() * f;
  return out;
}

nlohmann::json with_quality(double q, const nlohmann::json& overrides) {
  nlohmann::json out = quality_settings(q);
  if (!overrides.is_null()) out.merge_patch(overrides);
  return out;
}

}  // namespace btfvq
