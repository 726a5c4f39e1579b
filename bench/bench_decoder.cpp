// Single-thread throughput of Decoder::evaluate on a BTFBASE database (default: proposte):
//   bench_decoder BTFBASE_DIR      (e.g. ../shared/testdata/btfbase/proposte)
// Reports two access patterns: random (texel and directions uniformly random: cache-hostile) and
// coherent (an image: neighbouring texels under one light/view, as a renderer's inner loop sees it).
#include <chrono>
#include <ctime>
#include <cstdio>
#include <random>
#include <string>

#include "pipeline/btfbase.h"
#include "pipeline/decoder.h"

using namespace btfvq;

namespace {
// CPU time of this thread: the machine is shared, wall time would measure the neighbours.
double cpu_now() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}
}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: bench_decoder BTFBASE_DIR\n");
    return 2;
  }
  const std::string dir = argv[1];
  const Database db = import_btfbase(dir);
  const Decoder dec(db);
  const Material& mat = db.materials[0];
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> theta(0, 90), phi(0, 360);
  std::uniform_int_distribution<int> coord(0, 1 << 20);
  constexpr size_t kN = 1 << 20;
  struct Q {
    int x, y;
    Direction l, v;
  };
  std::vector<Q> random(kN);
  for (auto& q : random) q = {coord(rng), coord(rng), {theta(rng), phi(rng)}, {theta(rng), phi(rng)}};
  double sink = 0;
  auto t0 = cpu_now();
  for (const auto& q : random) sink += dec.evaluate(0, q.x, q.y, q.l, q.v).g;
  auto t1 = cpu_now();
  const double random_rate = double(kN) / (t1 - t0);
  // Coherent: whole images, one (light, view) pair each.
  size_t n = 0;
  t0 = cpu_now();
  for (int img = 0; img < 16; ++img) {
    const Direction l{theta(rng), phi(rng)}, v{theta(rng), phi(rng)};
    for (int y = 0; y < mat.height; ++y)
      for (int x = 0; x < mat.width; ++x, ++n) sink += dec.evaluate(0, x, y, l, v).g;
  }
  t1 = cpu_now();
  const double coherent_rate = double(n) / (t1 - t0);
  std::printf("%s: random %.2f M evaluations/s, coherent %.2f M evaluations/s (single thread, per CPU second; checksum %g)\n",
              dir.c_str(), random_rate / 1e6, coherent_rate / 1e6, sink);
  return 0;
}
