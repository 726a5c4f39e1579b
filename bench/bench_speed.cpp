// End-to-end compression of whole 256 x 256 samples (an easy, a medium and a hard synthetic preset)
// with default settings, split into stages: make the sample / resample / phase 1 / 2 / 3 / write.
// The real proposte sample's figures are in bench_realdata.
#include <filesystem>
#include <sstream>

#include "bench/bench_common.h"
#include "pipeline/encode/compress.h"
#include "pipeline/format/database.h"
#include "pipeline/io/synthetic.h"

using namespace btfvq;

int main(int argc, char** argv) {
  const auto args = bench::parse_args(argc, argv);
  const int size = args.quick ? 64 : 256;
  std::ostringstream md;
  nlohmann::json figures;
  md << "Whole " << size << " x " << size << " samples of `btfvq synth` (seed 1, LDR, 81 x 81 directions, "
     << double(size) * size * 6561 * 3 / 1e9
     << " GB raw each), default configs/pipeline.json, one fresh database each; wall seconds per stage on the "
        "shared 2-core machine (phases 1 and 2 grow the code-books on one thread while the next tile is "
        "resampled on the other; phase 3 searches on both). Peak memory is the process's resident maximum so "
        "far (it holds one raw sample at a time; resampled texels are held two tiles of 256 at a time, "
        "2 x 256 x 40656 floats = 83 MB, never the whole resampled sample: "
     << double(size) * size * 40656 * 4 / 1e9 << " GB at this size).\n\n"
     << "| preset | synth s | resample s | phase 1 / 2 / 3 s | phase-3 search | write s | total s | ratio | peak memory MB |\n"
        "|---|---|---|---|---|---|---|---|---|\n";
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
    const std::string search = r.json["search"]["path"].get<std::string>();
    std::snprintf(row, sizeof row, "| %s | %.0f | %.0f | %.0f / %.0f / %.0f | %s | %.1f | %.0f | 1:%.0f | %.0f |\n",
                  preset, synth_seconds, resample, ph[0]["seconds"].get<double>(), ph[1]["seconds"].get<double>(),
                  ph[2]["seconds"].get<double>(), search.c_str(), write_seconds, total, ratio, bench::peak_rss_mb());
    md << row;
    figures[preset] = {{"synth_seconds", synth_seconds}, {"resample_seconds", resample},
                       {"phase_seconds", {ph[0]["seconds"], ph[1]["seconds"], ph[2]["seconds"]}},
                       {"write_seconds", write_seconds}, {"total_seconds", total}, {"ratio", ratio},
                       {"peak_memory_mb", bench::peak_rss_mb()}};
    std::fprintf(stderr, "%s %d: %.0f s, 1:%.0f\n", preset, size, total, ratio);
  }
  md << "\nTotal = resample + phases + write (the time `btfvq compress` spends after loading its input); "
        "resampling overlaps the phases, so the stages add up to more than the total.\n";
  bench::write_section(args, "Whole-sample compression time and memory", 31, md.str(), figures);
  return 0;
}
