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
  // Composition: from texels this much farther than the P4 bound, when it gains this much.
  const double compose = shipped["schedule"]["compose_threshold"].get<double>();
  out["schedule"]["compose_threshold"] = std::min(2.0, compose * f);
  out["schedule"]["compose_gain"] = shipped["schedule"]["compose_gain"].get<double>() * f;
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
