#pragma once
// Shared plumbing of the bench_* programs: arguments from bench/run.sh, timing, peak memory, and the
// JSON section each program hands to bench/report.py.
#include <sys/resource.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include <btfvq/error.h>
#include "pipeline/util/args.h"

namespace btfvq::bench {

struct Args {
  std::filesystem::path json = "bench.json";
  std::filesystem::path scratch = "/tmp/btfvq-bench-scratch";
  std::filesystem::path testdata = "tests/data";
  std::filesystem::path figures = "bench/results";
  bool quick = false;  // smaller sizes, for trying a bench by hand
  btfvq::Args given;   // everything, also a bench's own options
};

// The options every bench takes, then a bench's own.
inline ArgSpec bench_spec(const std::string& program, const std::vector<Option>& own, const std::string& notes) {
  const Args d;
  std::vector<Option> values{{"json", "FILE", "where to write this program's section (default " + d.json.string() + ")"},
                             {"scratch", "DIR", "for files it writes on the way (default " + d.scratch.string() + ")"},
                             {"testdata", "DIR", "the test data (default " + d.testdata.string() + ")"},
                             {"figures", "DIR", "where figures go (default " + d.figures.string() + ")"}};
  values.insert(values.end(), own.begin(), own.end());
  return {program,
          program + " [--json FILE] [--scratch DIR] [--testdata DIR] [--figures DIR] [--quick]" + (own.empty() ? "" : " [OPTIONS]"),
          "a benchmark: writes one section of BENCHMARKS.md (bench/run.sh runs every one)",
          values,
          {{"quick", "", "smaller sizes, for trying a bench by hand"}},
          /*positionals=*/false,
          notes};
}

// A bench is run by a script or by hand: a bad argument ends it with status 2, --help with 0.
inline btfvq::Args parse_or_exit(const ArgSpec& spec, const std::vector<std::string>& words) {
  try {
    btfvq::Args given = btfvq::parse_args(spec, words);
    if (!given.has("help")) return given;
    std::cout << help_text(spec);
    std::exit(0);
  } catch (const InputError& e) {
    std::cerr << spec.program << ": error: " << e.what() << "\n";
    std::exit(2);
  }
}

// `own`: a bench's own options (read from Args::given), explained by `notes` in --help; `more`:
// arguments after argv's (e.g. from the environment).
inline Args parse_args(int argc, char** argv, const std::vector<Option>& own = {}, const std::string& notes = "",
                       const std::vector<std::string>& more = {}) {
  std::vector<std::string> words(argv + 1, argv + argc);
  words.insert(words.end(), more.begin(), more.end());
  Args a;
  a.given = parse_or_exit(bench_spec(std::filesystem::path(argv[0]).filename().string(), own, notes), words);
  a.json = a.given.get_or("json", a.json.string());
  a.scratch = a.given.get_or("scratch", a.scratch.string());
  a.testdata = a.given.get_or("testdata", a.testdata.string());
  a.figures = a.given.get_or("figures", a.figures.string());
  a.quick = a.given.has("quick");
  std::filesystem::create_directories(a.scratch);
  std::filesystem::create_directories(a.figures);
  return a;
}

class Stopwatch {
 public:
  Stopwatch() : start_(std::chrono::steady_clock::now()) {}
  double seconds() const { return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count(); }
  void reset() { start_ = std::chrono::steady_clock::now(); }

 private:
  std::chrono::steady_clock::time_point start_;
};

// Peak resident memory of this process so far, in MB.
inline double peak_rss_mb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_maxrss) / 1024.0;
}

// own_provenance: the markdown says which run measured each of its parts (results kept across runs),
// so BENCHMARKS.md does not stamp the whole section with the latest run.
inline void write_section(const Args& a, const std::string& title, int order, const std::string& markdown,
                          const nlohmann::json& figures, bool own_provenance = false) {
  std::ofstream out(a.json);
  out << nlohmann::json{{"title", title}, {"order", order}, {"markdown", markdown}, {"figures", figures},
                        {"own_provenance", own_provenance}}.dump(2);
}

}  // namespace btfvq::bench
