#include "pipeline/encode/target.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <optional>
#include <sstream>
#include <string>

#include <btfvq/error.h>
#include "pipeline/decode/reconstruct.h"
#include "pipeline/encode/ceiling.h"
#include "pipeline/encode/quality.h"
#include "pipeline/encode/resample.h"
#include "pipeline/format/database.h"
#include "pipeline/metrics/btf_cielab.h"
#include "pipeline/metrics/metrics.h"

namespace btfvq {

namespace {

// What the search needs of a metric: how to score an attempt, which way is better, how the metric
// moves per unit of quality before two attempts measure it, and when it is close enough. The loop
// below works on `direction * value` ("goodness", higher is better) so that it is written once.
struct MetricSpec {
  const char* name;
  double direction;  // +1: higher is better (MSSIM); -1: lower is better (BTF-CIELab)
  double slope;      // |change of the value| per quality unit, a first guess
  double tolerance;
  std::function<double(const MeasuredSample& reference, const MeasuredSample& decoded)> score;
};

MetricSpec metric_of(const QualityTarget& t) {
  if (t.metric == TargetMetric::Mssim) {
    if (!(t.value > 0 && t.value < 1)) throw InputError("target MSSIM must lie in (0, 1), got " + std::to_string(t.value));
    // About what the presets and proposte show (docs/encoder.md "Target").
    return {"mssim", 1, 0.002, t.tolerance.value_or(kMssimTolerance),
            [](const MeasuredSample& r, const MeasuredSample& d) { return evaluate(r, d).mssim_y; }};
  }
  if (!(t.value > 0 && std::isfinite(t.value)))
    throw InputError("target BTF-CIELab mean must be a number > 0, got " + std::to_string(t.value));
  // docs/metrics.md "BTF-CIELab as a target": about what leather shows (0.045 from Q 20 to 50, 0.034 to 70).
  return {"btf_cielab", -1, 0.04, t.tolerance.value_or(kBtfCielabTolerance),
          [c = t.condition](const MeasuredSample& r, const MeasuredSample& d) {
            return btf_cielab(r, d, {.condition = c}).mean;
          }};
}

struct Attempt {
  double quality = 0, goodness = 0;  // goodness = direction * the metric's value
  uint64_t bytes = 0;
  int n_phi_v = 0;  // the grid's azimuths
};

// The azimuths of the finer grid a new database may take when the configured grid's ceiling holds
// an MSSIM target down: the measured views lie on rings of up to 24 azimuths, which 16 phi_v nodes
// undersample (docs/encoder.md "Target": wool 128's ceiling 0.838 on 16, 0.971 on 24).
constexpr int kFinerPhiV = 24;

// What the progress says of the compression about to run at quality q (CompressProgress::attempt).
std::string describe_attempt(const std::vector<Attempt>& tried, double q, const nlohmann::json& overrides,
                             const MetricSpec& metric) {
  std::ostringstream s;
  s << "attempt " << tried.size() + 1 << ": quality " << std::round(q * 100) / 100;
  if (overrides.contains("grid") && overrides["grid"].contains("n_phi_v"))
    s << " on " << overrides["grid"]["n_phi_v"].get<int>() << " view azimuths";
  if (!tried.empty()) {
    const Attempt& last = tried.back();
    s << "; attempt " << tried.size() << " gave " << (metric.direction > 0 ? "MSSIM " : "BTF-CIELab mean ")
      << metric.direction * last.goodness << " at " << last.bytes << " bytes";
  }
  return s.str();
}

// Whether `a` is better kept than `b`: reaching the target beats not; among those that reach it
// fewer bytes, among those that do not the closer one.
bool better(const Attempt& a, const Attempt& b, double target) {
  const bool ra = a.goodness >= target, rb = b.goodness >= target;
  if (ra != rb) return ra;
  return ra ? a.bytes < b.bytes : a.goodness > b.goodness;
}

// The next quality to try: between the closest attempts on either side of the target (secant), or
// a step past the one side known so far, the slope taken from two attempts on one side when there
// are. Goodness rises with quality for every metric.
double next_quality(const std::vector<Attempt>& tried, double target, double first_slope) {
  const Attempt* below = nullptr;  // highest goodness under the target
  const Attempt* above = nullptr;  // lowest goodness at or over it
  for (const Attempt& a : tried) {
    if (a.goodness < target && (!below || a.goodness > below->goodness)) below = &a;
    if (a.goodness >= target && (!above || a.goodness < above->goodness)) above = &a;
  }
  if (below && above) {
    const double dm = above->goodness - below->goodness;
    // Aim a little past the interpolated point: reaching the target is what counts. Not within a
    // tenth of the bracket of either end: each step narrows it by that much at least, where the
    // curve is not straight between them.
    const double t = std::clamp(dm > 1e-9 ? (target - below->goodness) / dm * 1.1 : 0.5, 0.1, 0.9);
    return std::clamp(below->quality + t * (above->quality - below->quality), 0.0, 100.0);
  }
  const Attempt& last = tried.back();
  double slope = first_slope;
  if (tried.size() >= 2) {
    const Attempt& prev = tried[tried.size() - 2];
    if (std::abs(last.quality - prev.quality) > 1e-9)
      slope = std::max(first_slope / 20, (last.goodness - prev.goodness) / (last.quality - prev.quality));
  }
  const double step = std::clamp((target - last.goodness) / slope * 1.1, -40.0, 40.0);
  const double next = std::clamp(last.quality + (std::abs(step) < 2 ? (step < 0 ? -2.0 : 2.0) : step), 0.0, 100.0);
  // Into the growth range at most to the end of the phase-3 composition ramp from below: there the
  // metric can rise steeply (wool 32: 0.59 at Q 90, 0.92 at Q 92), and the compressions above cost
  // the more the higher they go (Q 100 grows every texel).
  if (last.quality <= kGrowthQuality && next > kGrowthQuality) return std::min(next, kComposeQuality);
  return next;
}

}  // namespace

CompressReport compress_to_target(Database& db, const MeasuredSample& sample, const std::string& name,
                                  const QualityTarget& target, const CompressOptions& options) {
  const MetricSpec metric = metric_of(target);
  const double goal = metric.direction * target.value;
  // A database with content keeps its grid; an empty one may take the finer grid below, unless the
  // user's settings name a grid.
  nlohmann::json overrides = target.overrides.is_null() ? nlohmann::json::object() : target.overrides;
  const bool grid_named = overrides.is_object() && overrides.contains("grid");
  if (has_content(db) && !grid_named) overrides["grid"] = grid_section(db.codebooks.grid);
  const bool grid_free = !has_content(db) && !grid_named;
  // What the search aims at: the target, or a little under the parametrization's ceiling where
  // the target lies above what any quality can give (measured once the first attempt misses).
  double aim = goal;
  std::optional<double> ceiling, first_ceiling;
  std::vector<Attempt> tried;
  // Only the kept attempt's database and report are held: a copy of the code-books each.
  Attempt best;
  Database best_db;
  CompressReport best_report;
  double q = kDefaultQuality;
  for (int k = 0; k < std::max(1, target.max_attempts); ++k) {
    Database trial = db;
    CompressOptions o = options;
    o.config = pipeline_config(with_quality(q, overrides), "target quality " + std::to_string(q));
    // Progress over every compression the search may run (one more where the grid may change).
    const double share = 1.0 / (std::max(1, target.max_attempts) + (grid_free ? 1 : 0));
    if (options.progress)
      o.progress = [&, done = tried.size(), what = describe_attempt(tried, q, overrides, metric)](CompressProgress p) {
        p.fraction = std::min(1.0, (double(done) + p.fraction) * share);
        p.attempt = what;
        options.progress(p);
      };
    CompressReport report = compress_material(trial, sample, name, o);
    quantize_new_rows(trial);  // score what the file will hold
    const double value = metric.score(sample, reconstruct_sample(trial, name, sample));
    const Attempt a{q, metric.direction * value, serialize_database(trial).size(), trial.codebooks.grid.n_phi_v};
    tried.push_back(a);
    int n_phi_v = a.n_phi_v;  // the grid of the next attempt
    if (k == 0 && !ceiling && a.goodness < goal && target.metric == TargetMetric::Mssim && !sample.is_hdr()) {
      ceiling = metric.score(sample, parametrization_roundtrip(sample, o.config));
      aim = std::min(goal, metric.direction * *ceiling - kCeilingMargin);
      // Held down by the grid: a new database takes the finer one if its ceiling is higher, and the
      // search goes on there with one attempt more (the one above stays a candidate, and guides the
      // next step: the finer grid scores about as high at the same quality, or higher).
      if (aim < goal && grid_free && trial.codebooks.grid.n_phi_v < kFinerPhiV) {
        nlohmann::json finer = overrides;
        finer["grid"]["n_phi_v"] = kFinerPhiV;
        const double c = metric.score(
            sample, parametrization_roundtrip(sample, pipeline_config(with_quality(q, finer), "the finer grid")));
        if (c > *ceiling) {
          first_ceiling = ceiling;
          ceiling = c;
          aim = std::min(goal, metric.direction * c - kCeilingMargin);
          overrides = std::move(finer);
          n_phi_v = kFinerPhiV;
          --k;
        }
      }
    }
    if (tried.size() == 1 || better(a, best, aim)) {
      best = a;
      best_db = std::move(trial);
      best_report = std::move(report);
    }
    if (a.goodness >= aim && a.goodness - aim <= metric.tolerance) break;
    if (a.goodness < aim && q >= 100) break;  // nothing higher to try
    if (a.goodness >= aim && q <= 0) break;
    const double next = next_quality(tried, aim, metric.slope);
    bool seen = false;
    // Steps of a twentieth of Q still matter: across the composition ramp MSSIM rises by 0.3 in two
    // units of Q (wool 128 ended at Q 92, 0.9415, when a step to Q 91.8 counted as seen under 0.5).
    for (const Attempt& t : tried) seen = seen || (t.n_phi_v == n_phi_v && std::abs(t.quality - next) < 0.05);
    if (seen) break;
    q = next;
  }
  nlohmann::json attempts = nlohmann::json::array();
  for (const Attempt& a : tried)
    attempts.push_back({{"quality", a.quality},
                        {metric.name, metric.direction * a.goodness},
                        {"bytes", a.bytes},
                        {"n_phi_v", a.n_phi_v}});
  nlohmann::json& j = best_report.json["target"];
  j = {{"metric", metric.name},
       {metric.name, target.value},
       {"achieved", metric.direction * best.goodness},
       {"quality", best.quality},
       {"reached", best.goodness >= goal},
       {"aimed", metric.direction * aim},
       {"bytes", best.bytes},
       {"ratio", compression_ratio(raw_bytes(best_db), best.bytes)},
       {"attempts", attempts}};
  if (ceiling) j["ceiling"] = *ceiling;
  if (first_ceiling) j["finer_grid"] = {{"n_phi_v", kFinerPhiV}, {"configured_ceiling", *first_ceiling}};
  if (target.metric == TargetMetric::BtfCielab) {
    j["resolution"] = target.condition.resolution;
    j["speed"] = target.condition.speed;
  }
  db = std::move(best_db);
  return best_report;
}

}  // namespace btfvq
