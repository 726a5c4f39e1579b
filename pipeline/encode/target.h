#pragma once
// A target quality instead of a setting: the knob of pipeline/encode/quality.h searched until a
// metric of the material on the whole sample reaches the target: its MSSIM (Y, over every measured
// image, as `btfvq eval` reports it; at least the target) or its BTF-CIELab mean (at the target's
// viewing condition, as `btfvq eval --metric btf-cielab` reports it; at most the target). Each
// attempt is a whole compression of the material into a copy of the database, decoded at the
// sample's directions and scored (docs/encoder.md "Target"): exact, at the price of a few
// compressions; the database keeps the attempt that reaches the target with the fewest bytes (or,
// if none does, the closest one).
#include <nlohmann/json.hpp>

#include "pipeline/encode/compress.h"

namespace btfvq {

// The shipped default target (README): chosen from the measured curves (docs/encoder.md "Target").
inline constexpr double kDefaultTargetMssim = 0.90;
// The BTF-CIELab targets the shells accept (`--target-btf-cielab`, job field "target_btf_cielab"):
// CIEDE2000 units; below 0.01 no quality reaches it, above 100 any does.
inline constexpr double kMinTargetBtfCielab = 0.01, kMaxTargetBtfCielab = 100;

// When the search stops: the target passed by at most this much (QualityTarget::tolerance unset).
inline constexpr double kMssimTolerance = 0.005;     // MSSIM units
inline constexpr double kBtfCielabTolerance = 0.1;   // CIEDE2000 units

// A target MSSIM above the parametrization's ceiling (pipeline/encode/ceiling.h) minus this is
// not reachable at any quality: the search aims at the ceiling minus this instead, the rule of
// "every preset reaches 0.90 or its ceiling minus 0.03" (docs/encoder.md "Target").
inline constexpr double kCeilingMargin = 0.03;  // MSSIM units

// compress_material() at the quality that reaches `target` (InputError for an MSSIM target outside
// (0, 1), a BTF-CIELab target not > 0). The report's json gains "target": {metric ("mssim" or
// "btf_cielab"), the target under the metric's name, achieved, quality, reached (the target),
// aimed (the target, or the ceiling minus kCeilingMargin below it), bytes, ratio, attempts:
// [{quality, <metric>, bytes}]}, "ceiling" when it was measured (an MSSIM target the first attempt,
// at the default quality, misses; LDR samples), and for BTF-CIELab the viewing condition
// (resolution, speed).
CompressReport compress_to_target(Database& db, const MeasuredSample& sample, const std::string& name,
                                  const QualityTarget& target, const CompressOptions& options);

}  // namespace btfvq
