// The executor: turns a job into a database with the pipeline library.
//
// Progress: each material gets an equal share of the job; within it, loading or synthesizing is
// the first 10 % and compress_material() the remaining 90 % (its own fraction). Writing the file
// is reported as the final stage.
#include <fstream>
#include <iterator>

#include "pipeline/encode/compress.h"
#include "pipeline/format/database.h"
#include <btfvq/error.h>
#include "pipeline/io/sample_io.h"
#include "pipeline/io/synthetic.h"
#include "server/executor.h"

namespace btfvq::server {
namespace {

constexpr double kLoadShare = 0.1;

std::vector<uint8_t> read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw CorruptError("cannot read the previous database version '" + path + "'");
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

MeasuredSample load_material(const MaterialSpec& m, const ProgressFn& progress, uint64_t max_expanded_bytes) {
  if (m.kind == "synthetic") {
    SynthOptions o;
    o.preset = m.preset;
    o.size = m.size;
    o.seed = uint64_t(m.seed);
    o.progress = progress;
    return synthesize(o);
  }
  // Uploads and server-side paths: a zip/tar or a directory in the UBO2003 layout, with the
  // zip-bomb limit.
  return load_sample(m.file, progress, max_expanded_bytes);
}

}  // namespace

Executor make_pipeline_executor() {
  return [](const JobSpec& spec, const std::string& previous, const std::string& out, JobContext& ctx) {
    std::vector<uint8_t> previous_bytes;
    Database db;
    if (!previous.empty()) {
      previous_bytes = read_bytes(previous);
      db = parse_database(previous_bytes, previous);
    }
    for (const auto& m : spec.materials)
      if (db.find(m.name)) throw InputError("database '" + spec.database + "' already has a material '" + m.name + "'");

    ParameterDictionary config = ParameterDictionary::embedded_default("pipeline");
    config.merge(ParameterDictionary(spec.pipeline, "job " + spec.id + " pipeline overrides"));

    const double n = double(spec.materials.size());
    for (size_t i = 0; i < spec.materials.size(); ++i) {
      const MaterialSpec& m = spec.materials[i];
      if (ctx.cancelled()) throw CancelledError();
      auto report = [&](JobProgress p, double within_material) {
        p.fraction = (double(i) + within_material) / n;
        p.material = m.name;
        ctx.progress(p);
      };
      const std::string load_stage = m.kind == "synthetic" ? "synthesize" : "load";
      report({load_stage, 0, 0, 0, 0, {}, m.name}, 0);
      const MeasuredSample sample = load_material(
          m,
          [&](size_t done, size_t total) {
            report({load_stage, 0, 0, done, total, {}, m.name}, total ? kLoadShare * double(done) / double(total) : 0);
          },
          ctx.max_expanded_bytes);
      if (ctx.cancelled()) throw CancelledError();

      CompressOptions options;
      options.config = config;
      options.cancelled = ctx.cancelled;
      options.progress = [&](const CompressProgress& p) {
        JobProgress jp{p.stage, p.phase, 0, p.texels_done, p.texels_total, {}, m.name};
        jp.codebook_sizes = p.sizes;
        report(jp, kLoadShare + (1 - kLoadShare) * p.fraction);
      };
      const CompressReport r = compress_material(db, sample, m.name, options);
      ctx.added.push_back({m.name, sample.raw_bytes(), sample.width(), sample.height(), r.json});
    }

    ctx.progress({"write", 0, 1.0, 0, 0, {}, ""});
    // Sections unchanged since the previous version are copied from it byte for byte.
    quantize_new_rows(db);
    const std::vector<uint8_t> bytes = serialize_database(db, {}, previous.empty() ? nullptr : &previous_bytes);
    std::ofstream file(out, std::ios::binary | std::ios::trunc);
    file.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
    file.close();
    if (!file) throw Error("io", "cannot write '" + out + "'");
  };
}

}  // namespace btfvq::server
