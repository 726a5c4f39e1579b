// probe_noise_floor SAMPLE DB [DB...]: how each database's own P6 assignment scores under the
// encoder's similarity against the resampled SAMPLE (every 8th texel in x and y), over the whole grid
// and over the interior nodes only (the ring of each (alpha, beta) plane left out; that score takes
// the LDR luminance range). With DB the original authors' database (`btfvq import-btfbase`) and
// SAMPLE its decoded JPEG folder, this is the noise floor a threshold must respect: proposte scores
// 0.44 on the whole grid and 0.17 inside, yet decodes to MSSIM 0.984 (docs/resampling.md, unseen nodes).
#include <algorithm>
#include <cstdio>
#include <vector>

#include <btfvq/error.h>
#include "pipeline/encode/encoder.h"
#include "pipeline/encode/resample.h"
#include "pipeline/format/database.h"
#include "pipeline/io/sample_io.h"

using namespace btfvq;

namespace {

void print(const char* db, const char* what, std::vector<double> v) {
  std::sort(v.begin(), v.end());
  double sum = 0;
  for (double x : v) sum += x;
  auto q = [&](double f) { return v[size_t(f * double(v.size() - 1))]; };
  std::printf("%s\t%s\tn %zu\tmean %.4f\tp10 %.4f\tp50 %.4f\tp90 %.4f\tmax %.4f\n", db, what, v.size(),
              sum / double(v.size()), q(0.1), q(0.5), q(0.9), v.back());
}

// The interior nodes (alpha, beta not at the ends) of every plane, plane-major per channel.
std::vector<float> interior(const AngularGrid& g, const std::vector<float>& texel) {
  std::vector<float> out;
  const size_t n = g.samples();
  for (int c = 0; c < 3; ++c)
    for (int p = 0; p < g.n_phi_v; ++p)
      for (int t = 0; t < g.n_theta_v; ++t)
        for (int a = 1; a < g.n_alpha - 1; ++a)
          for (int b = 1; b < g.n_beta - 1; ++b) out.push_back(texel[size_t(c) * n + g.index(p, t, a, b)]);
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: probe_noise_floor SAMPLE DB [DB...]\n");
    return 2;
  }
  try {
    const MeasuredSample sample = load_sample(argv[1]);
    for (int k = 2; k < argc; ++k) {
      const Database db = read_database(argv[k]);
      const Material& m = db.materials.at(0);
      if (m.width != sample.width() || m.height != sample.height())
        throw InputError(std::string(argv[k]) + ": its first material is not the sample's size");
      const AngularGrid& g = db.codebooks.grid;
      const ResampleOperator op(sample, g, ResampleSettings::defaults());
      const SimilaritySettings s = SimilaritySettings::defaults();
      const WindowGeometry inner(g.n_alpha - 2, g.n_beta - 2, s.window_radius);
      const int planes = g.n_phi_v * g.n_theta_v;
      std::vector<float> texel(op.values_per_texel()), recon(op.values_per_texel());
      std::vector<double> whole, inside;
      for (int y = 0; y < m.height; y += 8)
        for (int x = 0; x < m.width; x += 8) {
          const size_t t = size_t(y) * size_t(m.width) + size_t(x);
          if (m.p6_index[t] < 0) continue;
          op.apply(sample, t, 1, texel.data());
          reconstruct_texel(db.codebooks, m.dynamic, uint32_t(m.p6_index[t]), m.p6_scale[t], recon.data());
          whole.push_back(texel_dissimilarity(s, m.dynamic, g, texel.data(), recon.data()));
          const auto a = interior(g, texel), b = interior(g, recon);
          inside.push_back(1.0 - slice_similarity(s, m.dynamic, inner, a.data(), b.data(), planes, 0, 3, 255.0f));
        }
      print(argv[k], "whole grid", whole);
      print(argv[k], "interior", inside);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "probe_noise_floor: %s\n", e.what());
    return 1;
  }
  return 0;
}
