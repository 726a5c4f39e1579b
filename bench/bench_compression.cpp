// Compression of synthetic presets with default settings: ratio (raw LDR bytes / .btfdb bytes),
// MSSIM, PSNR, CIEDE2000, code-book sizes, time per stage and peak memory, all measured in one run.
#include <filesystem>
#include <sstream>

#include "bench/bench_common.h"
#include "pipeline/encode/compress.h"
#include "pipeline/format/database.h"
#include "pipeline/metrics/metrics.h"
#include "pipeline/decode/reconstruct.h"
#include "pipeline/io/synthetic.h"

using namespace btfvq;

int main(int argc, char** argv) {
  const auto args = bench::parse_args(argc, argv);
  const int size = args.quick ? 32 : 128;
  std::ostringstream md;
  nlohmann::json figures;
  md << "Every preset of `btfvq synth` at " << size << " x " << size
     << " (seed 1, LDR, 81 x 81 Bonn directions), compressed alone into a fresh database with the default "
        "configs/pipeline.json, then decoded at the measured directions and compared with its input. "
        "Ratio = raw bytes (W x H x 6561 x 3) / .btfdb bytes.\n\n"
     << "| preset | ratio | bytes | MSSIM (Y) | PSNR dB | CIEDE2000 mean / p95 | P1 | C | I1 | I2 | P2 | M | P3 | P4 | "
        "phase 1 / 2 / 3 s | total s |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  int passing = 0, presets = 0;
  for (const auto& p : synthetic_presets()) {
    SynthOptions o;
    o.preset = p.name;
    o.size = size;
    o.seed = 1;
    o.dynamic = Dynamic::LDR;
    const MeasuredSample sample = synthesize(o);
    bench::Stopwatch sw;
    Database db;
    const CompressReport r = compress_material(db, sample, p.name, {});
    quantize_new_rows(db);
    const auto path = args.scratch / (p.name + ".btfdb");
    write_database(db, path.string());
    const double seconds = sw.seconds();
    const uint64_t bytes = std::filesystem::file_size(path);
    const Database file = read_database(path.string());
    const EvaluationReport e = evaluate(sample, reconstruct_sample(file, p.name, sample));
    const double ratio = double(sample.raw_bytes()) / double(bytes);
    const auto& z = r.json["codebook_sizes"];
    const auto& ph = r.json["phases"];
    char row[768];
    std::snprintf(row, sizeof row, "| %s | 1:%.0f | %llu | %.3f | %.1f | %.2f / %.2f | %d | %d | %d | %d | %d | %d | %d | %d | %.0f / %.0f / %.0f | %.0f |\n",
                  p.name.c_str(), ratio, (unsigned long long)bytes, e.mssim_y, e.psnr, e.ciede2000_mean, e.ciede2000_p95,
                  z["P1"].get<int>(), z["C"].get<int>(), z["I1"].get<int>(), z["I2"].get<int>(), z["P2"].get<int>(),
                  z["M"].get<int>(), z["P3"].get<int>(), z["P4"].get<int>(), ph[0]["seconds"].get<double>(),
                  ph[1]["seconds"].get<double>(), ph[2]["seconds"].get<double>(), seconds);
    md << row;
    ++presets;
    passing += ratio >= 200 && e.mssim_y >= 0.80;
    figures[p.name] = {{"ratio", ratio}, {"bytes", bytes}, {"mssim", e.mssim_y}, {"psnr", e.psnr},
                       {"ciede2000_mean", e.ciede2000_mean}, {"ciede2000_p95", e.ciede2000_p95},
                       {"seconds", seconds}, {"report", r.json}};
    std::fprintf(stderr, "%s: ratio 1:%.0f MSSIM %.3f in %.0f s\n", p.name.c_str(), ratio, e.mssim_y, seconds);
  }
  md << "\nPresets with ratio >= 200 and MSSIM >= 0.80: **" << passing << " of " << presets
     << "**. Peak resident memory of the whole run: " << int(bench::peak_rss_mb()) << " MB.\n";
  figures["presets_meeting_200_and_0.80"] = passing;
  bench::write_section(args, "Compression of synthetic presets (default settings)", 30, md.str(), figures);
  return 0;
}
