#pragma once
// One knob for the rate-distortion trade-off: a quality Q in [0, 100] that sets every threshold, the
// share of texels that grow the code-books and the phase-3 composition by one documented rule
// (docs/encoder.md "Quality"), so that a user asks for more or less quality instead of tuning eight
// thresholds and three phase settings. Higher Q: every threshold lower or equal and more texels
// grown, so more entries and a closer reconstruction. The shipped defaults are Q = kDefaultQuality.
#include <nlohmann/json.hpp>

namespace btfvq {

inline constexpr double kDefaultQuality = 50;
// Above this quality the share of texels that grow the code-books rises too, up to every texel at
// Q = 100: the qualities whose compressions cost the most (quality.cpp says why).
inline constexpr double kGrowthQuality = 90;

// The pipeline settings (a configs/pipeline.json fragment: thresholds.ssim, schedule.phase*_fraction,
// schedule.relax_factor, schedule.compose_*, refine.merge_budget)
// that quality q stands for. InputError unless 0 <= q <= 100.
nlohmann::json quality_settings(double q);

// quality_settings(q) with `overrides` merged on top: the expert settings of a config file or a
// job's "pipeline" field win over the knob, key by key.
nlohmann::json with_quality(double q, const nlohmann::json& overrides);

}  // namespace btfvq
