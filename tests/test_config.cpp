#include <doctest/doctest.h>

#include <cmath>

#include "pipeline/encode/compress.h"
#include "pipeline/encode/encoder.h"
#include "pipeline/encode/resample.h"
#include "pipeline/encode/schedule.h"
#include "pipeline/util/config.h"
#include <btfvq/error.h>

using namespace btfvq;

TEST_CASE("every built-in default is read and typed") {
  auto d = ParameterDictionary::embedded_default("pipeline");
  CHECK(d.integer("grid.n_beta", 3, 1024) == 11);
  CHECK(d.string("device") == "auto");
}

TEST_CASE("a misspelled key is an error naming it") {
  auto d = ParameterDictionary::parse(R"({"grid": {"n_beta": 11, "n_alhpa": 11}})", "test.json");
  d.integer("grid.n_beta", 3, 1024);
  try {
    d.check_unused();
    FAIL("expected ConfigError");
  } catch (const ConfigError& e) {
    CHECK(std::string(e.what()).find("grid.n_alhpa") != std::string::npos);
    CHECK(std::string(e.what()).find("test.json") != std::string::npos);
  }
}

TEST_CASE("wrong types, out-of-range values and malformed JSON are ConfigErrors") {
  auto d = ParameterDictionary::parse(R"({"a": "x", "b": 2.5, "c": -1})", "t");
  CHECK_THROWS_AS(d.number("a", 0, 1), ConfigError);
  CHECK_THROWS_AS(d.integer("b", 0, 10), ConfigError);
  CHECK_THROWS_AS(d.number("c", 0, 1), ConfigError);
  CHECK_THROWS_AS(d.number("missing", 0, 1), ConfigError);
  CHECK_THROWS_AS(ParameterDictionary::parse("{\"a\": ", "t"), ConfigError);
  CHECK_THROWS_AS(ParameterDictionary::parse("[1, 2]", "t"), ConfigError);
  CHECK_THROWS_AS(ParameterDictionary::parse(R"({"d": 1e999})", "t"), ConfigError);  // overflow, not inf
}

TEST_CASE("overrides merge onto defaults and unknown override keys are reported") {
  auto d = ParameterDictionary::embedded_default("pipeline");
  d.merge(ParameterDictionary::parse(R"({"grid": {"n_beta": 21}, "bogus": 1})", "overrides"));
  CHECK(d.integer("grid.n_beta", 3, 1024) == 21);
  CHECK(d.integer("grid.n_alpha", 2, 1024) == 11);
  CHECK_THROWS_AS(d.check_unused(), ConfigError);
}

TEST_CASE("pipeline_config: the one check of user settings (CLI --config and job fields)") {
  const nlohmann::json shipped = ParameterDictionary::embedded_default("pipeline").json();
  CHECK(pipeline_config(nullptr, "none").json() == shipped);
  CHECK(pipeline_config(nlohmann::json::object(), "empty").json() == shipped);
  const ParameterDictionary d = pipeline_config({{"thresholds", {{"ssim", {{"p4", 0.2}}}}}}, "over.json");
  CHECK(d.number("thresholds.ssim.p4", 0, 2) == 0.2);
  CHECK(d.number("thresholds.ssim.p3", 0, 2) == shipped["thresholds"]["ssim"]["p3"].get<double>());
  auto rejects = [](const nlohmann::json& over, const std::string& key) {
    try {
      pipeline_config(over, "over.json");
      FAIL("accepted " << over.dump());
    } catch (const ConfigError& e) {
      CHECK(std::string(e.what()).find(key) != std::string::npos);
      CHECK(std::string(e.what()).find("over.json") != std::string::npos);
    }
  };
  rejects({{"schedule", {{"phase1_fractoin", 0.1}}}}, "phase1_fractoin");        // misspelled
  rejects({{"schedule", {{"tile_texels", 2.5}}}}, "tile_texels");                // an integer as 2.5
  rejects({{"schedule", {{"relax_factor", "2"}}}}, "relax_factor");              // wrong kind
  rejects({{"thresholds", {{"ssim", {{"p1", -1.0}}}}}}, "thresholds.ssim.p1");   // out of range
  rejects(nlohmann::json::array(), "over.json");
}

TEST_CASE("the settings structs carry no values of their own: defaults() is the shipped file") {
  const ParameterDictionary d = ParameterDictionary::embedded_default("pipeline");
  const nlohmann::json& j = d.json();
  const Thresholds t = Thresholds::defaults();
  CHECK(t.p4 == j["thresholds"]["ssim"]["p4"].get<double>());
  CHECK(t.p1 == j["thresholds"]["ssim"]["p1"].get<double>());
  CHECK(t.c == j["thresholds"]["ssim"]["c"].get<double>());
  CHECK(Thresholds::defaults(Metric::MSE).p4 == j["thresholds"]["mse"]["p4"].get<double>());
  const SimilaritySettings s = SimilaritySettings::defaults();
  CHECK(s.candidate_limit == j["similarity"]["candidate_limit"].get<int>());
  CHECK(s.proxy_bands == j["similarity"]["proxy_bands"].get<int>());
  CHECK(s.outlier_fraction == j["similarity"]["outlier_fraction"].get<double>());
  CHECK(ScheduleSettings::defaults().phase2_fraction == j["schedule"]["phase2_fraction"].get<double>());
  CHECK(ResampleSettings::defaults().light_neighbours == j["resample"]["light_neighbours"].get<int>());
  CHECK(Thresholds{}.p4 == 0);
  CHECK(SimilaritySettings{}.candidate_limit == 0);
  // AngularGrid{} is the grid of the original authors' databases (docs/btfbase-format.md); the
  // shipped grid is the same one, so that imported and new databases share code-books.
  const AngularGrid g{};
  CHECK(g.n_beta == j["grid"]["n_beta"].get<int>());
  CHECK(g.n_alpha == j["grid"]["n_alpha"].get<int>());
  CHECK(g.n_theta_v == j["grid"]["n_theta_v"].get<int>());
  CHECK(g.n_phi_v == j["grid"]["n_phi_v"].get<int>());
}
