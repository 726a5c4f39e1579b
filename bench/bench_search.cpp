// Phase 3 (the frozen search, pipeline/encode/frozen_search.h) on the same texels and the same code-books,
// by each path, in one run: the batched kernel on OpenCL (the default), its C++ reference and the
// pruned CPU search (the default without OpenCL). Also how the cost grows with the code-books (P4
// size), and phase 3 of a whole sample compressed once per path.
#include <numeric>
#include <sstream>

#include "bench/bench_common.h"
#include "pipeline/encode/compress.h"
#include "pipeline/util/config.h"
#include "pipeline/format/database.h"
#include "pipeline/encode/frozen_search.h"
#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/encode/resample.h"
#include "pipeline/encode/schedule.h"
#include "pipeline/io/synthetic.h"

using namespace btfvq;

namespace {

struct Timing {
  double seconds = 0;
  std::vector<P6Entry> entries;
  SearchStats stats;
};

Timing run(const Encoder& encoder, SearchPath path, const std::vector<float>& texels, size_t n) {
  Timing t;
  t.entries.resize(n);
  FrozenSearch search(encoder, path, 2);
  bench::Stopwatch sw;
  const size_t values = 3 * encoder.codebooks().grid.samples();
  for (size_t at = 0; at < n; at += 256) {
    const size_t m = std::min<size_t>(256, n - at);
    search.encode(texels.data() + at * values, m, t.entries.data() + at);
  }
  t.seconds = sw.seconds();
  t.stats = search.stats();
  return t;
}

// Phase 3 of a whole compression of `sample` with schedule.search = `search`.
struct WholeRun {
  double phase3_seconds = 0;
  std::vector<uint8_t> database;
};

WholeRun compress_with(const MeasuredSample& sample, const std::string& search) {
  CompressOptions o;
  o.config.merge(ParameterDictionary(nlohmann::json{{"schedule", {{"search", search}}}}, "bench_search"));
  Database db;
  const CompressReport r = compress_material(db, sample, "m", o);
  quantize_new_rows(db);
  return {r.json["phases"][2]["seconds"].get<double>(), serialize_database(db)};
}

}  // namespace

int main(int argc, char** argv) {
  const auto args = bench::parse_args(argc, argv);
  const int size = args.quick ? 32 : 64;
  SynthOptions o;
  o.preset = "leather";
  o.size = size;
  const MeasuredSample sample = synthesize(o);
  const ParameterDictionary config = ParameterDictionary::embedded_default("pipeline");
  const AngularGrid grid{config.integer("grid.n_beta", 3, 1024), config.integer("grid.n_alpha", 2, 1024),
                         config.integer("grid.n_theta_v", 2, 1024), config.integer("grid.n_phi_v", 1, 1024)};
  const ResampleOperator op(sample, grid, ResampleSettings::from(config));
  const size_t values = op.values_per_texel(), total = sample.texel_count();
  std::vector<float> texels(total * values);
  op.apply(sample, 0, total, texels.data());
  const std::vector<uint32_t> order = halton_order(size, size);
  auto texel = [&](size_t i) { return texels.data() + size_t(order[i]) * values; };

  const SimilaritySettings similarity = SimilaritySettings::from(config);
  const Thresholds thresholds = Thresholds::from(config);
  Codebooks books(grid);
  Encoder encoder(books, sample.dynamic(), thresholds, similarity);
  // Phase-3 texels: the last ones in Halton order, gathered once.
  const size_t probe = args.quick ? 128 : 512;
  std::vector<float> tail;
  for (size_t i = total - probe; i < total; ++i) tail.insert(tail.end(), texel(i), texel(i) + values);

  std::ostringstream md;
  nlohmann::json figures;
  md << "leather " << size << " x " << size << ", code-books grown by the growing phases on the first texels in Halton "
        "order, then " << probe << " phase-3 texels (the last in Halton order) searched with 32 candidates each "
        "(default `similarity.candidate_limit`). Device: " << ComputeDevice::get().description() << ".\n\n";

  // Cost of the pruned search as the code-books grow.
  const bool opencl = ComputeDevice::get().uses_opencl();
  md << "| texels grown | P4 entries | pruned texels/s (2 threads) | batched OpenCL texels/s |\n|---|---|---|---|\n";
  const size_t grow_to[] = {total / 100, total / 40, total / 20};
  size_t grown = 0;
  for (size_t target : grow_to) {
    encoder.set_thresholds(grown < total / 100 ? thresholds : thresholds.relaxed(2.5));
    for (; grown < std::max<size_t>(target, 1); ++grown) encoder.encode_growing(texel(grown));
    const Timing t = run(encoder, SearchPath::Pruned, tail, probe);
    const std::string p4 = std::to_string(books.p4_index.rows());
    md << "| " << grown << " | " << p4 << " | " << int(double(probe) / t.seconds) << " | ";
    figures["pruned_texels_per_s_by_p4"][p4] = double(probe) / t.seconds;
    if (opencl) {
      if (target == grow_to[0]) run(encoder, SearchPath::BatchedOpenCL, tail, 1);  // builds the program first
      const Timing b = run(encoder, SearchPath::BatchedOpenCL, tail, probe);
      md << int(double(probe) / b.seconds);
      figures["opencl_texels_per_s_by_p4"][p4] = double(probe) / b.seconds;
    } else {
      md << "-";
    }
    md << " |\n";
  }

  // The three paths on the final code-books.
  const Timing pruned = run(encoder, SearchPath::Pruned, tail, probe);
  const Timing reference = run(encoder, SearchPath::BatchedReference, tail, probe);
  md << "\n| path | texels/s | batch s | of which scoring s | settle s | candidates settled exactly | same entries as pruned |\n"
        "|---|---|---|---|---|---|---|\n";
  auto same = [&](const Timing& t) {
    size_t k = 0;
    for (size_t i = 0; i < probe; ++i) k += t.entries[i].index == pruned.entries[i].index && t.entries[i].scale == pruned.entries[i].scale;
    return k;
  };
  auto row = [&](const char* name, const Timing& t) {
    char line[512];
    std::snprintf(line, sizeof line, "| %s | %.0f | %.1f | %.1f | %.1f | %zu of %zu | %zu of %zu |\n", name,
                  double(probe) / t.seconds, t.stats.batch_seconds, t.stats.device_seconds, t.stats.settle_seconds, t.stats.settled,
                  t.stats.scored, same(t), probe);
    md << line;
    figures[name] = {{"texels_per_s", double(probe) / t.seconds}, {"same", same(t)}};
  };
  row("pruned (CPU; default without OpenCL)", pruned);
  if (opencl) {
    const Timing batched = run(encoder, SearchPath::BatchedOpenCL, tail, probe);
    row("batched, OpenCL kernel (default)", batched);
    row("batched, C++ reference", reference);
    md << "\nBatched: OpenCL / C++ reference **" << reference.seconds / batched.seconds << "x** (same work, same run; "
       << "scoring alone " << reference.stats.device_seconds / batched.stats.device_seconds << "x); "
       << "OpenCL / pruned **" << pruned.seconds / batched.seconds << "x**. Both batched paths make the same "
       << "decisions (one texel per work-item, candidates in proxy order abandoned by the pruned search's rule); "
       << "the host's share (building queries and candidate lists, settling ~1 candidate per texel exactly) is the "
       << "same on both.\n";
    figures["opencl_over_reference"] = reference.seconds / batched.seconds;
    figures["opencl_over_reference_scoring"] = reference.stats.device_seconds / batched.stats.device_seconds;
    figures["opencl_over_pruned"] = pruned.seconds / batched.seconds;
  } else {
    row("batched, C++ reference", reference);
    md << "\nNo OpenCL device: the batched kernel was not measured.\n";
  }
  if (opencl) {
    // The same comparison on phase 3 of a whole sample: the medium preset compressed once per path.
    SynthOptions w;
    w.preset = "leather";
    w.size = args.quick ? 48 : 128;
    const MeasuredSample whole = synthesize(w);
    const WholeRun a = compress_with(whole, "batched"), b = compress_with(whole, "batched-reference"),
                   c = compress_with(whole, "pruned");
    md << "\nPhase 3 of a whole sample: leather " << w.size << " x " << w.size << " compressed three times with "
       << "default settings except `schedule.search`; phase-3 wall seconds: batched OpenCL **" << a.phase3_seconds
       << "**, batched C++ reference **" << b.phase3_seconds << "**, pruned CPU **" << c.phase3_seconds
       << "**: OpenCL / C++ reference **" << b.phase3_seconds / a.phase3_seconds << "x**, OpenCL / pruned **"
       << c.phase3_seconds / a.phase3_seconds << "x**. The three databases are "
       << (a.database == b.database && a.database == c.database ? "byte-identical" : "NOT byte-identical")
       << " (" << a.database.size() << " bytes).\n";
    figures["whole_sample"] = {{"size", w.size},
                               {"phase3_seconds", {{"opencl", a.phase3_seconds}, {"reference", b.phase3_seconds},
                                                   {"pruned", c.phase3_seconds}}},
                               {"opencl_over_reference", b.phase3_seconds / a.phase3_seconds},
                               {"opencl_over_pruned", c.phase3_seconds / a.phase3_seconds},
                               {"identical", a.database == b.database && a.database == c.database}};
  }
  bench::write_section(args, "Phase 3 search paths", 36, md.str(), figures);
  return 0;
}
