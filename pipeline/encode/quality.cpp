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

// The share of texels that grow the code-books. Phase 3 can only compose P4 entries from the
// frozen P3 entries, so a material whose texels share little (wool) gains quality only by growing
// more of them: its MSSIM follows the grown share (wool 64: 0.50 at 6 %, 0.60 at 25 %, 0.83 = its
// ceiling minus 0.007 with every texel grown; docs/encoder.md "Quality"). Below the default the
// shares fall as the thresholds rise; above it phase 2 reaches every texel at Q = 100 on a
// geometric path that starts flat: growing is the slow, sequential part of the encoder, and on a
// material that shares (leather) tighter thresholds buy about the same MSSIM per byte sooner, so
// growth takes over only towards the top of the scale.
double phase1_fraction(double shipped, double q) { return shipped / threshold_factor(q); }

double phase2_fraction(double shipped, double phase1, double q) {
  const double all = 1.0 - phase1;
  if (q <= kDefaultQuality) return shipped / threshold_factor(q);
  const double t = (q - kDefaultQuality) / (100.0 - kDefaultQuality);
  return std::min(all, shipped * std::pow(all / shipped, t * t));
}

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
  // Growth: more texels grow, and phase 2 relaxes its thresholds less (2.5 at Q 50, 1.5 at Q 100).
  const nlohmann::json& schedule = shipped["schedule"];
  const double p1 = phase1_fraction(schedule["phase1_fraction"].get<double>(), q);
  out["schedule"]["phase1_fraction"] = p1;
  out["schedule"]["phase2_fraction"] = phase2_fraction(schedule["phase2_fraction"].get<double>(), p1, q);
  out["schedule"]["relax_factor"] = 1.0 + (schedule["relax_factor"].get<double>() - 1.0) * f;
  // Composition: from texels this much farther than the P4 bound, when it gains this much.
  out["schedule"]["compose_threshold"] = std::min(2.0, schedule["compose_threshold"].get<double>() * f);
  out["schedule"]["compose_gain"] = schedule["compose_gain"].get<double>() * f;
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
