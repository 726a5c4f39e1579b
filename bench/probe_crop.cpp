// probe_crop IN OUT X Y SIZE: a SIZE x SIZE crop at column X, row Y of a measured sample, written in
// the UBO2003 layout (JPEG quality 95 for LDR, as real archives), for fast encoder experiments on
// real data (the 64 x 64 crop of proposte at (96, 96) of docs/encoder.md "Tuning").
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include <btfvq/error.h>
#include "pipeline/io/sample_io.h"

using namespace btfvq;

int main(int argc, char** argv) {
  if (argc != 6) {
    std::fprintf(stderr, "usage: probe_crop IN OUT X Y SIZE\n");
    return 2;
  }
  try {
    const MeasuredSample in = load_sample(argv[1]);
    const int x0 = std::atoi(argv[3]), y0 = std::atoi(argv[4]), n = std::atoi(argv[5]);
    if (x0 < 0 || y0 < 0 || n <= 0 || x0 + n > in.width() || y0 + n > in.height()) throw InputError("crop outside the sample");
    std::vector<std::vector<Direction>> lights;
    for (size_t v = 0; v < in.view_count(); ++v) lights.push_back(in.lights(v));
    MeasuredSample out(n, n, in.views(), lights, in.dynamic());
    const size_t row = in.pair_count() * 3;
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) {
        const size_t from = (size_t(y0 + y) * size_t(in.width()) + size_t(x0 + x)) * row, to = (size_t(y) * n + x) * row;
        if (in.is_hdr())
          std::memcpy(out.hdr_data().data() + to, in.hdr_data().data() + from, row * sizeof(float));
        else
          std::memcpy(out.ldr_data().data() + to, in.ldr_data().data() + from, row);
      }
    write_sample(out, argv[2]);
  } catch (const Error& e) {
    std::fprintf(stderr, "probe_crop: %s\n", e.what());
    return 1;
  }
  return 0;
}
