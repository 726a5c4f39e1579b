#include <doctest/doctest.h>

#include <algorithm>

#include <btfvq/error.h>
#include "pipeline/decode/reconstruct.h"
#include "pipeline/encode/compress.h"
#include "pipeline/encode/target.h"
#include "pipeline/format/database.h"
#include "pipeline/io/synthetic.h"
#include "pipeline/metrics/metrics.h"

using namespace btfvq;

namespace {
MeasuredSample leather16() {
  SynthOptions o;
  o.preset = "leather";
  o.size = 16;
  o.seed = 2;
  return synthesize(o);
}

double independent_mssim(const Database& db, const MeasuredSample& sample) {
  return evaluate(sample, reconstruct_sample(db, "m", sample)).mssim_y;
}
}  // namespace

TEST_CASE("target MSSIM: the database keeps an attempt that reaches it, and says what it reached") {
  const MeasuredSample sample = leather16();
  Database plain;
  compress_material(plain, sample, "m", {});
  quantize_new_rows(plain);
  const double at_default = independent_mssim(plain, sample);

  // A target above what the default quality gives: the search must go up.
  QualityTarget t;
  t.mssim = std::min(0.99, at_default + 0.02);
  CompressOptions o;
  o.target = t;
  Database db;
  const CompressReport r = compress_to_target(db, sample, "m", t, o);
  const auto& j = r.json["target"];
  REQUIRE(j["reached"].get<bool>());
  CHECK(j["mssim"] == t.mssim);
  CHECK(j["achieved"].get<double>() >= t.mssim);
  CHECK(j["quality"].get<double>() > 50);
  CHECK(j["attempts"].size() <= size_t(t.max_attempts));
  // What it reports is what the database decodes to, measured here on its own.
  CHECK(independent_mssim(db, sample) == doctest::Approx(j["achieved"].get<double>()).epsilon(1e-9));
  // Of the attempts that reached the target, the kept one has the fewest bytes.
  for (const auto& a : j["attempts"])
    if (a["mssim"].get<double>() >= t.mssim) CHECK(a["bytes"].get<uint64_t>() >= serialize_database(db).size());
}

TEST_CASE("target MSSIM out of reach: the closest attempt, marked not reached; a bad target changes nothing") {
  const MeasuredSample sample = leather16();
  QualityTarget t;
  t.mssim = 0.999;
  t.max_attempts = 2;
  Database db;
  const CompressReport r = compress_to_target(db, sample, "m", t, {});
  const auto& j = r.json["target"];
  CHECK_FALSE(j["reached"].get<bool>());
  double best = 0;
  for (const auto& a : j["attempts"]) best = std::max(best, a["mssim"].get<double>());
  CHECK(j["achieved"].get<double>() == best);
  CHECK(j["attempts"].size() == 2);

  Database untouched;
  for (double bad : {0.0, 1.0, -0.5}) {
    QualityTarget b;
    b.mssim = bad;
    CHECK_THROWS_AS(compress_to_target(untouched, sample, "m", b, {}), InputError);
  }
  CHECK(untouched.materials.empty());
}
