// The executor: a job's fields become options for one compress_database() call; this file only
// maps its progress onto the job's (the library gives each material an equal share of the job, the
// first tenth of it for loading or synthesizing) and records what was added.
#include "pipeline/encode/compress.h"
#include "pipeline/io/sample_io.h"
#include "pipeline/io/synthetic.h"
#include "server/executor.h"

namespace btfvq::server {
namespace {

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
    if (spec.target_mssim > 0) options.target = QualityTarget{spec.target_mssim, spec.pipeline};
    options.cancelled = ctx.cancelled;
    options.checkpoint_folder = ctx.work_folder;
    if (remote) options.remote_phase3 = [&](const PhaseThreeWork& w) { remote(spec, ctx, w); };
    options.progress = [&](const CompressProgress& p) {
      ctx.progress({p.stage, p.phase, p.fraction, p.texels_done, p.texels_total, p.sizes, p.material, p.resumed_tile});
    };
    const DatabaseSummary summary = compress_database(previous, inputs, out, options);
    for (const CompressReport& r : summary.added) ctx.added.push_back({r.material, r.raw_bytes, r.width, r.height, r.json});
  };
}

}  // namespace btfvq::server
