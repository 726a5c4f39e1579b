// Decoding throughput on the real BTFBASE databases: single-thread Decoder::evaluate, and the batch
// decode (Decoder::decode_opencl, kernels/decode.cl) against its C++ reference
// (Decoder::decode_reference) on the same queries in the same run. Two access patterns: random
// (texel and directions uniformly random: cache-hostile) and coherent (whole images under one
// light/view, as a renderer's inner loop sees them). Paper Sec. 6: 0.31-1.36 M evaluations/s on one
// core.
//
// The machine is shared, so besides wall time every rate is also given per CPU second (of this
// thread for single-thread figures, of the whole process, PoCL's workers included, for the batch):
// that figure drops much less when the neighbours are busy, and cores x it estimates what the batch
// reaches on an idle machine.
#include <algorithm>
#include <cmath>
#include <ctime>
#include <random>
#include <sstream>
#include <thread>
#include <tuple>

#include "bench/bench_common.h"
#include "pipeline/io/btfbase.h"
#include "pipeline/decode/decoder.h"
#include "pipeline/io/image.h"
#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/decode/reconstruct.h"

using namespace btfvq;

namespace {

double cpu_seconds(clockid_t clock) {
  timespec ts{};
  clock_gettime(clock, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}
double thread_cpu() { return cpu_seconds(CLOCK_THREAD_CPUTIME_ID); }
double process_cpu() { return cpu_seconds(CLOCK_PROCESS_CPUTIME_ID); }

// Wall and CPU time of one run of f.
struct Timing {
  double wall = 0, cpu = 0;
};
template <class F>
Timing timed(F&& f, bool whole_process) {
  const double c0 = whole_process ? process_cpu() : thread_cpu();
  bench::Stopwatch sw;
  f();
  return {sw.seconds(), (whole_process ? process_cpu() : thread_cpu()) - c0};
}

std::vector<DecodeQuery> random_queries(size_t n, std::mt19937& rng) {
  std::uniform_real_distribution<double> theta(0, 90), phi(0, 360);
  std::uniform_int_distribution<int> coord(0, 1 << 20);
  std::vector<DecodeQuery> q(n);
  for (auto& e : q) e = {0, coord(rng), coord(rng), {theta(rng), phi(rng)}, {theta(rng), phi(rng)}};
  return q;
}

// Whole images of material 0, row-major, each under its own random light and view.
std::vector<DecodeQuery> coherent_queries(const Material& mat, size_t n, std::mt19937& rng) {
  std::uniform_real_distribution<double> theta(0, 90), phi(0, 360);
  std::vector<DecodeQuery> q;
  q.reserve(n + size_t(mat.width) * size_t(mat.height));
  while (q.size() < n) {
    const Direction l{theta(rng), phi(rng)}, v{theta(rng), phi(rng)};
    for (int y = 0; y < mat.height; ++y)
      for (int x = 0; x < mat.width; ++x) q.push_back({0, x, y, l, v});
  }
  q.resize(n);
  return q;
}

struct Pattern {
  double single_cpu = 0;           // evaluate(), per thread CPU second
  Timing reference, opencl;        // the batch, n queries each
  double max_difference = 0;       // max |OpenCL - reference| / max(1, |reference|) over every channel
};

Pattern measure(const Decoder& dec, const std::vector<DecodeQuery>& queries) {
  Pattern r;
  const size_t n = queries.size();
  double sink = 0;
  const Timing single = timed(
      [&] {
        for (const auto& q : queries) sink += dec.evaluate(q.material, q.x, q.y, q.light, q.view).g;
      },
      false);
  r.single_cpu = double(n) / single.cpu;
  std::vector<Rgb> ref, cl;
  r.reference = timed([&] { ref = dec.decode_reference(queries); }, true);
  if (ComputeDevice::get().uses_opencl()) {
    dec.decode_opencl(queries);  // builds the kernel and uploads the code-books: once per decoder
    r.opencl = timed([&] { cl = dec.decode_opencl(queries); }, true);
    for (size_t i = 0; i < n; ++i)
      for (auto [a, b] : {std::pair{ref[i].r, cl[i].r}, std::pair{ref[i].g, cl[i].g}, std::pair{ref[i].b, cl[i].b}})
        r.max_difference = std::max(r.max_difference, double(std::abs(a - b)) / std::max(1.0, double(std::abs(a))));
    sink += cl[0].g;
  }
  if (sink == 42.0) std::fprintf(stderr, " ");  // keep the loops from being optimised away
  return r;
}

double mega(double count, double seconds) { return seconds > 0 ? count / seconds / 1e6 : 0.0; }

}  // namespace

int main(int argc, char** argv) {
  const auto args = bench::parse_args(argc, argv);
  const size_t n = args.quick ? (1 << 18) : (1 << 21);
  const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
  std::ostringstream md;
  nlohmann::json figures;
  md << "The original compressor's databases (tests/data/btfbase), " << n
     << " queries per pattern: random (texel and both directions uniformly random) and coherent (whole images "
        "of the material, each under one random light and view). M/s = million evaluations per second. "
        "Single-thread: Decoder::evaluate per CPU second of the thread. Batch: one call of Decoder::decode_opencl "
        "(kernels/decode.cl, "
     << ComputeDevice::get().description()
     << ") and of its C++ reference Decoder::decode_reference on the same queries, in wall time and per CPU "
        "second of the whole process (the machine is shared; "
     << cores << " cores x the per-CPU-second rate estimates what an idle machine gives).\n\n"
     << "| material | pattern | single-thread (M/s) | batch OpenCL (M/s wall) | batch OpenCL (M/CPU-s) | "
        "batch C++ reference (M/s wall) | OpenCL / reference (wall) | max rel. difference |\n"
     << "|---|---|---|---|---|---|---|---|\n";
  for (const char* name : {"alu", "proposte"}) {
    const Database db = import_btfbase((args.testdata / "btfbase" / name).string());
    const Decoder dec(db);
    std::mt19937 rng(1);
    for (const char* pattern : {"random", "coherent"}) {
      const auto queries =
          std::string(pattern) == "random" ? random_queries(n, rng) : coherent_queries(db.materials[0], n, rng);
      const Pattern r = measure(dec, queries);
      const double cl_wall = mega(double(n), r.opencl.wall), cl_cpu = mega(double(n), r.opencl.cpu);
      const double ref_wall = mega(double(n), r.reference.wall);
      char row[512];
      std::snprintf(row, sizeof row, "| %s | %s | %.2f | %.2f | %.2f | %.2f | %.1fx | %.1e |\n", name, pattern,
                    r.single_cpu / 1e6, cl_wall, cl_cpu, ref_wall, ref_wall > 0 ? cl_wall / ref_wall : 0.0,
                    r.max_difference);
      md << row;
      figures[name][pattern] = {{"single_thread_per_cpu_s", r.single_cpu},
                                {"batch_opencl_per_s", cl_wall * 1e6},
                                {"batch_opencl_per_cpu_s", cl_cpu * 1e6},
                                {"batch_reference_per_s", ref_wall * 1e6},
                                {"batch_reference_per_cpu_s", mega(double(n), r.reference.cpu) * 1e6},
                                {"max_relative_difference", r.max_difference}};
      std::fprintf(stderr, "%s", row);
    }
  }
  md << "\nPaper (Sec. 6, one core of a 2.83 GHz Xeon): 0.31-1.36 M evaluations/s depending on coherence. "
        "The batch kernel computes in float (the reference in double); the last column is the largest "
        "difference to the reference over every channel of every query.\n";
  // A picture of the real fabric as our decoder sees it (docs/btfbase-format.md's rules), for a person to check.
  const Database proposte = import_btfbase((args.testdata / "btfbase" / "proposte").string());
  for (const auto& [light, view, file] : {std::tuple{Direction{0, 0}, Direction{0, 0}, "proposte_l0-0_v0-0.png"},
                                          std::tuple{Direction{45, 120}, Direction{30, 60}, "proposte_l45-120_v30-60.png"}}) {
    write_rgb8_image((args.figures / file).string(), 256, 256, decode_image(proposte, "proposte", light, view));
    md << "\n![proposte, light " << light.theta << "," << light.phi << ", view " << view.theta << "," << view.phi
       << "](bench/results/" << file << ")";
  }
  md << "\n\nproposte decoded by btfvq from the original compressor's database (tests/data/btfbase/proposte).\n";
  bench::write_section(args, "Decoding throughput", 40, md.str(), figures);
  return 0;
}
