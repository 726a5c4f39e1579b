#include <doctest/doctest.h>

#include <cmath>
#include <string>

#include <btfvq/error.h>
#include "pipeline/encode/compress.h"
#include "pipeline/encode/encoder.h"
#include "pipeline/encode/quality.h"
#include "pipeline/encode/schedule.h"
#include "pipeline/util/config.h"
#include "pipeline/io/sample_io.h"
#include "pipeline/io/synthetic.h"
#include "support/measured_compression.h"
#include "support/test_paths.h"

using namespace btfvq;

namespace {
const char* kKeys[] = {"p4", "p3", "m", "p2", "p1", "i2", "i1", "c"};

ParameterDictionary at(double q) { return pipeline_config(quality_settings(q), "quality"); }
}  // namespace

TEST_CASE("the default quality is the shipped settings") {
  const ParameterDictionary shipped = ParameterDictionary::embedded_default("pipeline");
  CHECK(at(kDefaultQuality).json() == shipped.json());
}

TEST_CASE("higher quality: every threshold lower or equal, the top ones strictly, and each setting valid") {
  for (double q = 0; q < 100; q += 2.5) {
    CAPTURE(q);
    const ParameterDictionary lo = at(q), hi = at(q + 2.5);  // pipeline_config validates both
    for (const char* k : kKeys) {
      CAPTURE(k);
      const double a = lo.json()["thresholds"]["ssim"][k], b = hi.json()["thresholds"]["ssim"][k];
      CHECK(b <= a);
    }
    CHECK(double(hi.json()["thresholds"]["ssim"]["p4"]) < double(lo.json()["thresholds"]["ssim"]["p4"]));
    CHECK(double(hi.json()["schedule"]["compose_threshold"]) <= double(lo.json()["schedule"]["compose_threshold"]));
    CHECK(double(hi.json()["schedule"]["compose_gain"]) <= double(lo.json()["schedule"]["compose_gain"]));
    CHECK(double(hi.json()["refine"]["merge_budget"]) < double(lo.json()["refine"]["merge_budget"]));
    // Up to Q 90 the thresholds carry the scale and the phases stay as shipped; above it more
    // texels grow the code-books and phase 2 relaxes its thresholds less.
    const nlohmann::json& a = lo.json()["schedule"];
    const nlohmann::json& b = hi.json()["schedule"];
    const nlohmann::json shipped = ParameterDictionary::embedded_default("pipeline").json()["schedule"];
    for (const char* k : {"phase1_fraction", "phase2_fraction", "relax_factor"}) {
      CAPTURE(k);
      if (q + 2.5 <= 90) CHECK(b[k] == shipped[k]);
    }
    CHECK(b["compose_p3"] == (q + 2.5 > 90));
    // The share of phase-3 texels that may compose P3 entries rises from none just above Q 90 to
    // all from kComposeQuality on.
    if (q > 90) CHECK(double(b["compose_p3_share"]) >= double(a["compose_p3_share"]));
    if (q >= 90 && q + 2.5 <= kComposeQuality) CHECK(double(b["compose_p3_share"]) > double(a["compose_p3_share"]));
    if (q + 2.5 >= kComposeQuality || q + 2.5 <= 90) CHECK(double(b["compose_p3_share"]) == 1.0);
    if (q >= 90) {
      CHECK(double(b["phase1_fraction"]) > double(a["phase1_fraction"]));
      CHECK(double(b["phase2_fraction"]) > double(a["phase2_fraction"]));
      CHECK(double(b["relax_factor"]) < double(a["relax_factor"]));
    }
  }
  // Continuous at Q 90: just above it almost no texel composes a P3 entry.
  CHECK(double(at(90.001).json()["schedule"]["compose_p3_share"]) == doctest::Approx(0.0005));
  // At Q 100 every texel grows the code-books: phase 3 has nothing left to compose from frozen ones.
  const nlohmann::json top = at(100).json()["schedule"];
  CHECK(double(top["phase1_fraction"]) + double(top["phase2_fraction"]) == doctest::Approx(1.0));
  CHECK(double(top["relax_factor"]) == doctest::Approx(1.5));
  // The ends of the scale: three times looser and three times tighter than the default.
  const double p4 = Thresholds::defaults().p4;
  CHECK(Thresholds::from(at(0)).p4 == doctest::Approx(3 * p4));
  CHECK(Thresholds::from(at(100)).p4 == doctest::Approx(p4 / 3));
}

TEST_CASE("quality out of range is an InputError; expert settings win over the knob") {
  for (double q : {-1.0, 100.5, 1e300})
    CHECK_THROWS_AS(quality_settings(q), InputError);
  CHECK_THROWS_AS(quality_settings(std::nan("")), InputError);
  const nlohmann::json merged = with_quality(90, {{"thresholds", {{"ssim", {{"p2", 0.3}}}}}});
  CHECK(merged["thresholds"]["ssim"]["p2"] == 0.3);
  CHECK(merged["thresholds"]["ssim"]["p4"] == quality_settings(90)["thresholds"]["ssim"]["p4"]);
  // A misspelled expert setting is still refused by the one check.
  CHECK_THROWS_AS(pipeline_config(with_quality(90, {{"thresholds", {{"ssim", {{"p5", 0.3}}}}}}), "x"), ConfigError);
}

TEST_CASE("--quality is monotone end to end: tile, leather and fabric at 64 x 64, higher Q never gives lower MSSIM or fewer bytes") {
  for (const char* preset : {"tile", "leather", "fabric"}) {
    CAPTURE(preset);
    // As a user has it: a JPEG archive, read back.
    SynthOptions o;
    o.preset = preset;
    o.size = 64;
    o.seed = 1;
    const std::string zip = (test::scratch_dir(std::string("quality-") + preset) / "sample.zip").string();
    write_sample(synthesize(o), zip);
    const MeasuredSample sample = load_sample(zip);
    double last_mssim = 0;
    uint64_t last_bytes = 0;
    for (double q : {20.0, 40.0, 60.0, 80.0}) {
      CAPTURE(q);
      const auto [bytes, mssim] = test::compress_and_measure(sample, at(q));
      // Tile sits at its ceiling from Q 20 on (one P4 entry, MSSIM 0.997): there the steps move
      // MSSIM by +-1e-4 and the file by one P1 row more or less (3,240-3,285 bytes: greedy growth
      // in texel order can match a row at a tighter threshold that a looser one had inserted
      // differently). That, 1 % of the bytes where MSSIM moved by less than 1e-3, is all the
      // slack allowed; everywhere else bytes grow.
      CHECK(mssim >= last_mssim - 5e-4);
      const bool at_ceiling = std::abs(mssim - last_mssim) < 1e-3;
      CHECK(double(bytes) >= double(last_bytes) * (at_ceiling ? 0.99 : 1.0));
      last_mssim = mssim;
      last_bytes = bytes;
    }
  }
}

TEST_CASE("the proxies' luminance bands: leather at 64 x 64 comes out smaller than with one band, MSSIM no lower") {
  // Per-plane means (P3) and row means (M) cannot tell entries whose light falls on different sides
  // of a plane apart, so with one band the searches' 32 proxy-nearest candidates often miss the
  // SSIM-best entry.
  SynthOptions o;
  o.preset = "leather";
  o.size = 64;
  o.seed = 2;
  const std::string zip = (test::scratch_dir("proxy-bands") / "sample.zip").string();
  write_sample(synthesize(o), zip);
  const MeasuredSample sample = load_sample(zip);
  REQUIRE(SimilaritySettings::defaults().proxy_bands > 1);
  auto run = [&](const nlohmann::json& overrides) {
    return test::compress_and_measure(sample, pipeline_config(overrides, "test"));
  };
  const auto [banded_bytes, banded_mssim] = run(nlohmann::json::object());
  const auto [one_bytes, one_mssim] = run({{"similarity", {{"proxy_bands", 1}}}});
  MESSAGE("one band " << one_bytes << " B, MSSIM " << one_mssim << "; shipped " << banded_bytes << " B, MSSIM "
                      << banded_mssim);
  CHECK(banded_bytes < one_bytes);
  CHECK(banded_mssim >= one_mssim - 1e-4);
}
