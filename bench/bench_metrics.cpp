// Time of evaluate() on a full Bonn sample (81 x 81 images) of the given size, LDR.
//   bench_metrics [size=128] [threads=2]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <random>

#include "pipeline/metrics.h"

int main(int argc, char** argv) {
  const int size = argc > 1 ? std::atoi(argv[1]) : 128;
  const int threads = argc > 2 ? std::atoi(argv[2]) : 2;
  btfvq::MeasuredSample ref = btfvq::make_bonn_sample(size, size, btfvq::Dynamic::LDR);
  btfvq::MeasuredSample test = btfvq::make_bonn_sample(size, size, btfvq::Dynamic::LDR);
  std::mt19937 rng(1);
  std::uniform_int_distribution<int> v(0, 255), noise(-8, 8);
  for (size_t i = 0; i < ref.ldr_data().size(); ++i) {
    const int r = v(rng);
    ref.ldr_data()[i] = uint8_t(r);
    test.ldr_data()[i] = uint8_t(std::clamp(r + noise(rng), 0, 255));
  }
  const auto t0 = std::chrono::steady_clock::now();
  const btfvq::EvaluationReport rep = btfvq::evaluate(ref, test, threads);
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("%dx%d, %zu images, %d threads: %.2f s  (MSSIM Y %.4f Cb %.4f Cr %.4f, PSNR %.2f dB, dE00 mean %.3f p95 %.3f)\n",
              size, size, rep.images, threads, s, rep.mssim_y, rep.mssim_cb, rep.mssim_cr, rep.psnr,
              rep.ciede2000_mean, rep.ciede2000_p95);
}
