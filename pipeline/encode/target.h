#pragma once
// A target quality instead of a setting: the knob of pipeline/encode/quality.h searched until the
// material's MSSIM (Y, over every measured image, as `btfvq eval` reports it) reaches the target on
// the whole sample. Each attempt is a whole compression of the material into a copy of the
// database, decoded at the sample's directions and scored (docs/encoder.md "Target"): exact, at the
// price of a few compressions; the database keeps the attempt that reaches the target with the
// fewest bytes (or, if none does, the closest one).
#include <nlohmann/json.hpp>

#include "pipeline/encode/compress.h"

namespace btfvq {

// The shipped default target (README): chosen from the measured curves (docs/encoder.md "Target").
inline constexpr double kDefaultTargetMssim = 0.90;

// compress_material() at the quality that reaches `target` (InputError for a target outside
// (0, 1)). The report's json gains "target": {mssim, achieved, quality, reached, attempts: [{quality,
// mssim, bytes}]}.
CompressReport compress_to_target(Database& db, const MeasuredSample& sample, const std::string& name,
                                  const QualityTarget& target, const CompressOptions& options);

}  // namespace btfvq
