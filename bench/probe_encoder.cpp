// Encodes a material with the default pipeline config and reports texels/s per phase (wall and
// CPU), code-book sizes and the dissimilarity of the result.
//   probe_encoder synth [W] [ssim|mse|JSON]   synthetic W x W material (tests/support/synthetic_texels.h)
//   probe_encoder alu DIR [ssim|mse|JSON]     node values of DIR = .../testdata/btfbase/alu (64 x 64, the
//                                        original compressor's database: already through MLVQ once)
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <memory>
#include <stdexcept>
#include <string>

#include "pipeline/util/config.h"
#include "pipeline/encode/schedule.h"
#include "../tests/support/synthetic_texels.h"

using namespace btfvq;

namespace {

template <class T>
Table<T> load_matrix(const std::string& path, int* rows_out = nullptr, int* cols_out = nullptr) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read " + path);
  size_t rows, cols;
  double lo, hi;
  in >> rows >> cols >> lo >> hi;
  Table<T> t(cols);
  std::vector<T> row(cols);
  for (size_t r = 0; r < rows; ++r) {
    for (auto& v : row) {
      double d;
      in >> d;
      v = T(d);
    }
    t.append(row.data());
  }
  if (rows_out) *rows_out = int(rows);
  if (cols_out) *cols_out = int(cols);
  return t;
}

struct AluSource {
  Codebooks k;
  Table<int> p6;
  Table<float> p6s;
  int width = 0, height = 0;
  explicit AluSource(const std::string& dir) : k(AngularGrid{}) {
    k.p1 = load_matrix<float>(dir + "/all_PDF1Dslice.txt");
    k.c = load_matrix<float>(dir + "/all_colors.txt");
    k.i1 = load_matrix<uint32_t>(dir + "/all_indexAB.txt");
    k.i2 = load_matrix<uint32_t>(dir + "/all_PDF2Dcolours.txt");
    k.p2_index = load_matrix<uint32_t>(dir + "/all_PDF2Dslices.txt");
    k.p2_scale = load_matrix<float>(dir + "/all_PDF2Dscale.txt");
    k.m = load_matrix<uint32_t>(dir + "/all_PDF2Dindices.txt");
    k.p3_index = load_matrix<uint32_t>(dir + "/all_PDF3Dslices.txt");
    k.p3_scale = load_matrix<float>(dir + "/all_PDF3Dscale.txt");
    k.p4_index = load_matrix<uint32_t>(dir + "/all_PDF4Dslices.txt");
    k.p4_scale = load_matrix<float>(dir + "/all_PDF4Dscale.txt");
    p6 = load_matrix<int>(dir + "/alu_PDF6Dslices.txt", &height, &width);
    p6s = load_matrix<float>(dir + "/alu_PDF6Dscale.txt");
  }
  TexelSource source() const {
    return [this](const uint32_t* ids, size_t n, float* out) {
      for (size_t i = 0; i < n; ++i) {
        const int x = int(ids[i] % uint32_t(width)), y = int(ids[i] / uint32_t(width));
        reconstruct_texel(k, Dynamic::LDR, uint32_t(p6.at(size_t(y), size_t(x)) - 1), p6s.at(size_t(y), size_t(x)),
                          out + i * 3 * k.grid.samples());
      }
    };
  }
};

}  // namespace

int main(int argc, char** argv) {
  const std::string mode = argc > 1 ? argv[1] : "synth";
  const int w = mode == "synth" && argc > 2 ? std::atoi(argv[2]) : 64;
  const char* metric = argc > 3 ? argv[3] : nullptr;
  if (mode == "alu" && argc < 3) {
    std::fprintf(stderr, "usage: probe_encoder alu DIR [ssim|mse]\n");
    return 2;
  }
  auto cfg = ParameterDictionary::embedded_default("pipeline");
  // The last argument: a metric name, or a JSON object of pipeline config overrides.
  if (metric && metric[0] == '{') cfg.merge(ParameterDictionary::parse(metric, "args"));
  else if (metric) cfg.merge(ParameterDictionary::parse(std::string("{\"similarity\": {\"metric\": \"") + metric + "\"}}", "args"));
  const SimilaritySettings sim = SimilaritySettings::from(cfg);
  const Thresholds thr = Thresholds::from(cfg, sim.metric);
  const ScheduleSettings sch = ScheduleSettings::from(cfg);
  test::SyntheticMaterial mat(w, w);
  std::unique_ptr<AluSource> alu;
  TexelSource source = mat.source();
  int width = w, height = w;
  if (mode == "alu") {
    alu = std::make_unique<AluSource>(argv[2]);
    source = alu->source();
    width = alu->width;
    height = alu->height;
  }
  Codebooks books(AngularGrid{});
  const std::clock_t c0 = std::clock();
  const ScheduleResult r = run_schedule(books, Dynamic::LDR, width, height, source, thr, sim, sch);
  const double cpu = double(std::clock() - c0) / CLOCKS_PER_SEC;
  for (int p = 0; p < 3; ++p) {
    const auto& s = r.report.sizes[p];
    std::printf("phase %d: %zu texels in %.2f s (%.1f texels/s); sizes P1 %zu C %zu I1 %zu I2 %zu P2 %zu M %zu P3 %zu P4 %zu\n",
                p + 1, r.report.texels[p], r.report.seconds[p],
                r.report.seconds[p] > 0 ? double(r.report.texels[p]) / r.report.seconds[p] : 0.0, s[CodebookId::P1], s[CodebookId::C], s[CodebookId::I1], s[CodebookId::I2],
                s[CodebookId::P2], s[CodebookId::M], s[CodebookId::P3], s[CodebookId::P4]);
  }
  double mean = 0, worst = 0;
  for (float d : r.dissimilarity) {
    mean += d;
    worst = std::max(worst, double(d));
  }
  std::printf("cpu %.2f s; dissimilarity mean %.4f worst %.4f; comparisons %llu pruned %llu fallbacks %llu\n", cpu,
              mean / double(r.dissimilarity.size()), worst, (unsigned long long)r.report.encoder.comparisons,
              (unsigned long long)r.report.encoder.pruned, (unsigned long long)r.report.encoder.fallbacks);
  return 0;
}
