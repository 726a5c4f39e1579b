#include "pipeline/encode/target.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <string>

#include <btfvq/error.h>
#include "pipeline/decode/reconstruct.h"
#include "pipeline/encode/quality.h"
#include "pipeline/format/database.h"
#include "pipeline/metrics/metrics.h"

namespace btfvq {

namespace {

struct Attempt {
  double quality = 0, mssim = 0;
  uint64_t bytes = 0;
};

// Whether `a` is better kept than `b`: reaching the target beats not; among those that reach it
// fewer bytes, among those that do not a higher MSSIM.
bool better(const Attempt& a, const Attempt& b, double target) {
  const bool ra = a.mssim >= target, rb = b.mssim >= target;
  if (ra != rb) return ra;
  return ra ? a.bytes < b.bytes : a.mssim > b.mssim;
}

// The next quality to try: between the closest attempts on either side of the target (secant), or
// a step past the one side known so far, the slope taken from two attempts on one side when there are.
double next_quality(const std::vector<Attempt>& tried, double target) {
  const Attempt* below = nullptr;  // highest MSSIM under the target
  const Attempt* above = nullptr;  // lowest MSSIM at or over it
  for (const Attempt& a : tried) {
    if (a.mssim < target && (!below || a.mssim > below->mssim)) below = &a;
    if (a.mssim >= target && (!above || a.mssim < above->mssim)) above = &a;
  }
  if (below && above) {
    const double dm = above->mssim - below->mssim;
    const double t = dm > 1e-9 ? (target - below->mssim) / dm : 0.5;
    // Aim a little past the interpolated point: reaching the target is what counts.
    return std::clamp(below->quality + std::clamp(t * 1.1, 0.1, 0.9) * (above->quality - below->quality), 0.0, 100.0);
  }
  const Attempt& last = tried.back();
  double slope = 0.002;  // MSSIM per quality unit, about what the presets and proposte show
  if (tried.size() >= 2) {
    const Attempt& prev = tried[tried.size() - 2];
    if (std::abs(last.quality - prev.quality) > 1e-9) slope = std::max(1e-4, (last.mssim - prev.mssim) / (last.quality - prev.quality));
  }
  const double step = std::clamp((target - last.mssim) / slope * 1.1, -40.0, 40.0);
  return std::clamp(last.quality + (std::abs(step) < 2 ? (step < 0 ? -2.0 : 2.0) : step), 0.0, 100.0);
}

}  // namespace

CompressReport compress_to_target(Database& db, const MeasuredSample& sample, const std::string& name,
                                  const QualityTarget& target, const CompressOptions& options) {
  if (!(target.mssim > 0 && target.mssim < 1)) throw InputError("target MSSIM must lie in (0, 1), got " + std::to_string(target.mssim));
  std::vector<Attempt> tried;
  // Only the kept attempt's database and report are held: a copy of the code-books each.
  Attempt best;
  Database best_db;
  CompressReport best_report;
  double q = kDefaultQuality;
  for (int k = 0; k < std::max(1, target.max_attempts); ++k) {
    Database trial = db;
    CompressOptions o = options;
    o.config = pipeline_config(with_quality(q, target.overrides), "target quality " + std::to_string(q));
    const double share = 1.0 / std::max(1, target.max_attempts);
    if (options.progress)
      o.progress = [&, k](CompressProgress p) {
        p.fraction = std::min(1.0, (k + p.fraction) * share);
        options.progress(p);
      };
    CompressReport report = compress_material(trial, sample, name, o);
    quantize_new_rows(trial);  // score what the file will hold
    const Attempt a{q, evaluate(sample, reconstruct_sample(trial, name, sample)).mssim_y, serialize_database(trial).size()};
    tried.push_back(a);
    if (tried.size() == 1 || better(a, best, target.mssim)) {
      best = a;
      best_db = std::move(trial);
      best_report = std::move(report);
    }
    if (a.mssim >= target.mssim && a.mssim - target.mssim <= target.tolerance) break;
    if (a.mssim < target.mssim && q >= 100) break;  // nothing higher to try
    if (a.mssim >= target.mssim && q <= 0) break;
    const double next = next_quality(tried, target.mssim);
    bool seen = false;
    for (const Attempt& t : tried) seen = seen || std::abs(t.quality - next) < 0.5;
    if (seen) break;
    q = next;
  }
  nlohmann::json attempts = nlohmann::json::array();
  for (const Attempt& a : tried) attempts.push_back({{"quality", a.quality}, {"mssim", a.mssim}, {"bytes", a.bytes}});
  best_report.json["target"] = {{"mssim", target.mssim}, {"achieved", best.mssim}, {"quality", best.quality},
                                {"reached", best.mssim >= target.mssim}, {"attempts", attempts}};
  db = std::move(best_db);
  return best_report;
}

}  // namespace btfvq
