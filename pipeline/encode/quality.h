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
// From kGrowthQuality up to this quality the share of phase-3 texels that may compose new P3
// entries rises from none to all (quality.cpp): a ramp, so that MSSIM follows Q across the step
// that switching them on at once is for a material like wool (0.59 -> 0.91 on wool 32).
inline constexpr double kComposeQuality = 92;

// The pipeline settings (a configs/pipeline.json fragment: thresholds.ssim, schedule.phase*_fraction,
// schedule.relax_factor, schedule.compose_*, refine.merge_budget)
// that quality q stands for. InputError unless 0 <= q <= 100.
nlohmann::json quality_settings(double q);

// quality_settings(q) with `overrides` merged on top: the expert settings of a config file or a
// job's "pipeline" field win over the knob, key by key.
nlohmann::json with_quality(double q, const nlohmann::json& overrides);

}  // namespace btfvq
