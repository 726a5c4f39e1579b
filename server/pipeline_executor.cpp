// The executor: a job's fields become options for one compress_database() call; this file only
// maps its progress onto the job's (the library gives each material an equal share of the job, the
// first tenth of it for loading or synthesizing) and records what was added, with the BTF-CIELab of
// each added material when the job asks for it.
#include <algorithm>

#include <btfvq/error.h>
#include "pipeline/decode/reconstruct.h"
#include "pipeline/encode/compress.h"
#include "pipeline/format/database.h"
#include "pipeline/io/sample_io.h"
#include "pipeline/io/synthetic.h"
#include "server/executor.h"

namespace btfvq::server {
namespace {

// The share of a job that scores BTF-CIELab, when asked: on a 256 x 256 sample it takes minutes
// (BENCHMARKS.md "BTF-CIELab in eval"), the compression about an hour.
constexpr double kBtfCielabShare = 0.05;

nlohmann::json btf_cielab_json(const BtfCielabReport& r) {
  return {{"mean", r.mean},
          {"std", r.stddev},
          {"rms", r.rms},
          {"resolution", r.condition.resolution},
          {"speed", r.condition.speed},
          {"seconds", r.seconds}};
}

// Each added material's BTF-CIELab against its sample, decoded from the file the job publishes, by
// the calls of `btfvq eval --metric btf-cielab`: so the job reports what eval of the published
// database reports. The file and not the in-memory code-books, because the values of a version are
// quantized over all of the job's materials at once when it is written; and the sample is loaded
// again, because compress_database() holds one sample at a time and frees it after its material.
void score_btf_cielab(const std::vector<MaterialInput>& inputs, const std::string& out, const ViewingCondition& condition,
                      JobContext& ctx) {
  const Database db = read_database(out);
  std::vector<MaterialRecord>& added = ctx.added;
  for (size_t i = 0; i < added.size(); ++i) {
    if (ctx.cancelled()) throw CancelledError();
    MaterialRecord& m = added[i];
    ctx.progress({"btf_cielab", 0, 1 - kBtfCielabShare * (1 - double(i) / double(added.size())), i, added.size(),
                  CodebookSizes::of(db.codebooks), m.name});
    const auto input = std::find_if(inputs.begin(), inputs.end(), [&](const MaterialInput& in) { return in.name == m.name; });
    if (input == inputs.end()) throw Error("internal", "no input for the added material '" + m.name + "'");
    const MeasuredSample sample = input->load([](size_t, size_t) {});
    m.report["btf_cielab"] = btf_cielab_json(btf_cielab(sample, reconstruct_sample(db, m.name, sample), {.condition = condition}));
  }
}

MaterialInput input_of(const MaterialSpec& m, uint64_t max_expanded_bytes) {
  if (m.kind == "synthetic")
    return {m.name, "synthesize", [m](const ProgressFn& progress) {
              SynthOptions o;
              o.preset = m.preset;
              o.size = m.size;
              o.seed = uint64_t(m.seed);
              o.progress = progress;
              return synthesize(o);
            },
            m.preset + " " + std::to_string(m.size) + " " + std::to_string(m.seed)};
  // Uploads and server-side paths: a zip/tar or a directory in the UBO2003 layout, with the
  // zip-bomb limit.
  return {m.name, "load", [file = m.file, max_expanded_bytes](const ProgressFn& progress) {
            return load_sample(file, progress, max_expanded_bytes);
          },
          m.kind + " " + m.upload_id + " " + m.file};
}

}  // namespace

Executor make_pipeline_executor(RemotePhaseThree remote) {
  return [remote](const JobSpec& spec, const std::string& previous, const std::string& out, JobContext& ctx) {
    std::vector<MaterialInput> inputs;
    for (const auto& m : spec.materials) inputs.push_back(input_of(m, ctx.max_expanded_bytes));
    CompressOptions options;
    options.config = pipeline_config(spec.pipeline, "job " + spec.id + " pipeline overrides");
    if (spec.target_mssim > 0 || spec.target_btf_cielab > 0) {
      QualityTarget target;
      target.metric = spec.target_mssim > 0 ? TargetMetric::Mssim : TargetMetric::BtfCielab;
      target.value = spec.target_mssim > 0 ? spec.target_mssim : spec.target_btf_cielab;
      target.overrides = spec.pipeline;
      options.target = target;
    }
    options.cancelled = ctx.cancelled;
    options.checkpoint_folder = ctx.work_folder;
    if (remote) options.remote_phase3 = [&](const PhaseThreeWork& w) { remote(spec, ctx, w); };
    const double compress_share = spec.btf_cielab ? 1 - kBtfCielabShare : 1;
    options.progress = [&](const CompressProgress& p) {
      ctx.progress({p.stage, p.phase, compress_share * p.fraction, p.texels_done, p.texels_total, p.sizes, p.material,
                    p.resumed_tile, p.attempt});
    };
    const DatabaseSummary summary = compress_database(previous, inputs, out, options);
    for (const CompressReport& r : summary.added) ctx.added.push_back({r.material, r.raw_bytes, r.width, r.height, r.json});
    if (spec.btf_cielab) score_btf_cielab(inputs, out, *spec.btf_cielab, ctx);
  };
}

}  // namespace btfvq::server
