#pragma once
// Shared plumbing of the bench_* programs: arguments from bench/run.sh, timing, peak memory, and the
// JSON section each program hands to bench/report.py.
#include <sys/resource.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>

namespace btfvq::bench {

struct Args {
  std::filesystem::path json = "bench.json";
  std::filesystem::path scratch = "/tmp/btfvq-bench-scratch";
  std::filesystem::path testdata = "tests/data";
  std::filesystem::path figures = "bench/results";
  bool quick = false;  // smaller sizes, for trying a bench by hand
};

inline Args parse_args(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    auto next = [&]() -> std::string { return i + 1 < argc ? argv[++i] : ""; };
    if (k == "--json") a.json = next();
    else if (k == "--scratch") a.scratch = next();
    else if (k == "--testdata") a.testdata = next();
    else if (k == "--figures") a.figures = next();
    else if (k == "--quick") a.quick = true;
    else {
      std::cerr << "unknown argument " << k << "\n";
      std::exit(2);
    }
  }
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
