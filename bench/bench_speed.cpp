// End-to-end compression of whole 256 x 256 samples (an easy, a medium and a hard synthetic preset)
// with default settings, split into stages: make the sample / resample / phase 1 / 2 / 3 / write.
// The real proposte sample's figures are in bench_realdata.
#include <filesystem>
#include <sstream>

#include "bench/bench_common.h"
#include "pipeline/compress.h"
#include "pipeline/database.h"
#include "pipeline/synthetic.h"

using namespace btfvq;

int main(int argc, char** argv) {
  const auto args = bench::parse_args(argc, argv);
  const int size = args.quick ? 64 : 256;
  std::ostringstream md;
  nlohmann::json figures;
  md << "Whole " << size << " x " << size << " samples of `btfvq synth` (seed 1, LDR, 81 x 81 directions, "
     << double(size) * size * 6561 * 3 / 1e9
     << " GB raw each), default configs/pipeline.json, one fresh database each; wall seconds per stage on the "
        "shared 2-core machine (phases 1 and 2 grow the code-books on one thread, phase 3 searches on two). "
        "Peak memory is the process's resident maximum after the run (it holds one raw sample at a time; the "
        "encoder resamples a tile of 256 texels at a time).\n\n"
     << "| preset | synth s | resample s | phase 1 / 2 / 3 s | write s | total s | ratio | peak memory MB |\n"
        "|---|---|---|---|---|---|---|---|\n";
  for (const char* preset : {"tile", "leather", "wool"}) {
    bench::Stopwatch sw;
    SynthOptions o;
    o.preset = preset;
    o.size = size;
    const MeasuredSample sample = synthesize(o);
    const double synth_seconds = sw.seconds();
    sw.reset();
    Database db;
    const CompressReport r = compress_material(db, sample, preset, {});
    bench::Stopwatch write_sw;
    quantize_new_rows(db);
    const auto path = args.scratch / (std::string(preset) + ".btfdb");
    write_database(db, path.string());
    const double write_seconds = write_sw.seconds(), total = sw.seconds();
    const double ratio = double(sample.raw_bytes()) / double(std::filesystem::file_size(path));
    const auto& ph = r.json["phases"];
    const double resample = r.json["seconds"]["resample"].get<double>() + r.json["seconds"]["resample_operator"].get<double>();
    char row[512];
    std::snprintf(row, sizeof row, "| %s | %.0f | %.0f | %.0f / %.0f / %.0f | %.1f | %.0f | 1:%.0f | %.0f |\n", preset,
                  synth_seconds, resample, ph[0]["seconds"].get<double>(), ph[1]["seconds"].get<double>(),
                  ph[2]["seconds"].get<double>(), write_seconds, total, ratio, bench::peak_rss_mb());
    md << row;
    figures[preset] = {{"synth_seconds", synth_seconds}, {"resample_seconds", resample},
                       {"phase_seconds", {ph[0]["seconds"], ph[1]["seconds"], ph[2]["seconds"]}},
                       {"write_seconds", write_seconds}, {"total_seconds", total}, {"ratio", ratio},
                       {"peak_memory_mb", bench::peak_rss_mb()}};
    std::fprintf(stderr, "%s %d: %.0f s, 1:%.0f\n", preset, size, total, ratio);
  }
  md << "\nTotal = resample + phases + write (the time `btfvq compress` spends after loading its input).\n";
  bench::write_section(args, "Whole-sample compression time and memory", 31, md.str(), figures);
  return 0;
}
