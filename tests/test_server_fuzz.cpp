// A small version of the bench's fuzz (bench/bench_soak.py, issue 21 part 4): 600 random requests
// from a fixed seed to every endpoint of the real btfvq-server on loopback (junk methods, paths,
// headers, bodies). No answer may be a 5xx, the server must not exit, /healthz must answer
// afterwards and the data directory must hold no temporary file (the script checks all of it and
// exits 1 with --strict otherwise).
#include <doctest/doctest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "support/test_paths.h"

using namespace btfvq::test;
namespace fs = std::filesystem;

TEST_CASE("fuzz: 600 random requests to every endpoint, no 5xx, no crash, no temporary file left") {
  const fs::path dir = scratch_dir("server-fuzz");
  const fs::path json = dir / "fuzz.json";
  std::string output;
  const int status = run_command("python3 " + (source_dir() / "bench" / "bench_soak.py").string() + " --bin " +
                                     bin_dir().string() + " --scratch " + (dir / "scratch").string() + " --json " +
                                     json.string() + " --only fuzz --fuzz-requests 600 --seed 7 --strict",
                                 &output);
  if (status != 0) MESSAGE(output);
  CHECK(status == 0);
  REQUIRE(fs::exists(json));
  const auto figures = nlohmann::json::parse(std::ifstream(json))["figures"]["fuzz"];
  MESSAGE("fuzz: " << figures["classes"].dump());
  CHECK(figures["requests"] == 600);
  CHECK(figures["classes"]["5xx"] == 0);
  CHECK(figures["crashed"].is_null());
  CHECK(figures["healthz_after"] == true);
  CHECK(figures["stray_files"].empty());
}
