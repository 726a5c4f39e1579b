#include <doctest/doctest.h>

#include <cmath>

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
