#include "pipeline/encode/compress.h"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <set>

#include <unistd.h>

#include <btfvq/error.h>
#include "pipeline/encode/checkpoint.h"
#include "pipeline/encode/target.h"
#include "pipeline/format/database.h"
#include "pipeline/util/atomic_file.h"
#include "pipeline/util/sha256.h"
#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/encode/resample.h"

namespace btfvq {

namespace {

// Every setting the pipeline reads, in one place, so that validation and compression agree.
struct PipelineSettings {
  std::string device;
  AngularGrid grid;
  ResampleSettings resample;
  SimilaritySettings similarity;
  Thresholds thresholds;
  ScheduleSettings schedule;
};

PipelineSettings read_settings(const ParameterDictionary& config) {
  PipelineSettings s;
  s.device = config.string("device");
  s.grid = grid_settings(config);
  s.resample = ResampleSettings::from(config);
  s.similarity = SimilaritySettings::from(config);
  s.thresholds = Thresholds::from(config, s.similarity.metric);
  s.schedule = ScheduleSettings::from(config);
  config.check_unused();
  return s;
}

// Rough share of the total work per stage, for one progress fraction (phase 1 grows code-books
// texel by texel and costs far more per texel than the frozen search of phase 3).
constexpr double kStageStart[4] = {0.0, 0.02, 0.35, 0.55};
constexpr double kStageEnd[4] = {0.02, 0.35, 0.55, 1.0};

nlohmann::json refine_json(const ScheduleReport& r) {
  nlohmann::json steps = nlohmann::json::array();
  for (const RefineStep& s : r.refine) steps.push_back({{"mse_before", s.mse_before}, {"mse_after", s.mse_after}});
  return {{"texels", r.refine_texels}, {"iterations", steps}, {"seconds", r.refine_seconds}};
}

}  // namespace

void validate_pipeline_config(const ParameterDictionary& config) { read_settings(config); }

namespace {

std::string type_name(const nlohmann::json& v) {
  if (v.is_number_integer()) return "an integer";
  if (v.is_number()) return "a number";
  if (v.is_boolean()) return "true or false";
  if (v.is_string()) return "a string";
  if (v.is_array()) return "an array";
  if (v.is_object()) return "an object";
  return "null";
}

// Every override key must exist in the defaults with the same kind of value: the getters would
// catch most mistakes too, but only for keys they read, and not an integer given as 2.5.
void check_against(const nlohmann::json& defaults, const nlohmann::json& overrides, const std::string& prefix) {
  for (const auto& [key, value] : overrides.items()) {
    const std::string where = prefix + "." + key;
    if (!defaults.contains(key)) throw ConfigError(where + ": unknown key (not in configs/pipeline.json)");
    const auto& d = defaults[key];
    const bool same_kind = (d.is_number() && value.is_number()) || (d.is_string() && value.is_string()) ||
                           (d.is_boolean() && value.is_boolean()) || (d.is_array() && value.is_array()) ||
                           (d.is_object() && value.is_object());
    if (!same_kind || (d.is_number_integer() && !value.is_number_integer()))
      throw ConfigError(where + ": must be " + type_name(d) + " (got " + value.dump() + ")");
    if (d.is_object()) check_against(d, value, where);
  }
}

void check_material_name(const std::string& name) {
  if (name.empty() || name.size() > 200 || name.find_first_of("/\\\n\r\t") != std::string::npos)
    throw InputError("material name '" + name + "' must be 1-200 characters without slashes or control characters");
}

}  // namespace

ParameterDictionary pipeline_config(const nlohmann::json& overrides, const std::string& origin) {
  ParameterDictionary config = ParameterDictionary::embedded_default("pipeline");
  if (overrides.is_null()) return config;
  if (!overrides.is_object()) throw ConfigError(origin + ": must be a JSON object");
  check_against(config.json(), overrides, origin);
  config.merge(ParameterDictionary(overrides, origin));
  validate_pipeline_config(config);
  return config;
}

namespace {

// The schedule asks for texels in Halton order: gather them into a small contiguous sample and
// resample that in one call, so a scattered tile costs one launch.
TexelSource texel_source(const MeasuredSample& sample, const ResampleOperator& op, double* seconds) {
  const size_t pairs = sample.pair_count();
  std::vector<std::vector<Direction>> lights;
  for (size_t v = 0; v < sample.view_count(); ++v) lights.push_back(sample.lights(v));
  // The gathered tile is kept for the next call: a fresh one (5 MB for 256 LDR texels) per call
  // costs mostly page faults. A call that finds it in use (calls overlapping) gathers into its own.
  struct Spare {
    std::mutex mutex;
    std::optional<MeasuredSample> tile;
  };
  auto spare = std::make_shared<Spare>();
  return [&sample, &op, seconds, pairs, lights, spare](const uint32_t* ids, size_t n, float* out) {
    const auto t = std::chrono::steady_clock::now();
    std::unique_lock<std::mutex> kept(spare->mutex, std::try_to_lock);
    std::optional<MeasuredSample> own;
    std::optional<MeasuredSample>& slot = kept.owns_lock() ? spare->tile : own;
    if (!slot || size_t(slot->width()) != n) slot.emplace(int(n), 1, sample.views(), lights, sample.dynamic());
    MeasuredSample& tile = *slot;
    for (size_t i = 0; i < n; ++i) {
      const size_t from = size_t(ids[i]) * pairs * 3, to = i * pairs * 3;
      if (sample.is_hdr())
        std::memcpy(tile.hdr_data().data() + to, sample.hdr_data().data() + from, pairs * 3 * sizeof(float));
      else
        std::memcpy(tile.ldr_data().data() + to, sample.ldr_data().data() + from, pairs * 3);
    }
    op.apply(tile, 0, n, out);
    *seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
  };
}

// Thrown by a checkpoint callback to end run_schedule early (the tiles are done elsewhere, or the
// range of a tile part is complete).
struct StopSchedule {};

// Where one material's checkpoints go (compress_database with a work folder).
struct MaterialCheckpoints {
  CheckpointFolder& folder;
  size_t input = 0, first_new = 0;        // the input's position; db.materials this work added start here
  const PhaseThreeState* resume = nullptr;  // continue phase 3 from here
};

CompressReport compress_one(Database& db, const MeasuredSample& sample, const std::string& name,
                            const CompressOptions& options, const MaterialCheckpoints* checkpoints) {
  const PipelineSettings s = read_settings(options.config);
  check_material_name(name);
  if (db.find(name)) throw InputError("the database already has a material named '" + name + "'");
  if (sample.texel_count() == 0 || sample.pair_count() == 0) throw InputError("the sample is empty");
  if (has_content(db) && !(db.codebooks.grid == s.grid))
    throw InputError("the database's angular grid differs from the configured grid");
  if (!has_content(db)) db.codebooks = Codebooks(s.grid);
  ComputeDevice::configure(s.device);

  using clock = std::chrono::steady_clock;
  auto seconds_since = [](clock::time_point t) { return std::chrono::duration<double>(clock::now() - t).count(); };
  const PhaseThreeState* resume = checkpoints ? checkpoints->resume : nullptr;
  const int64_t resumed_tile = resume ? int64_t(resume->tiles_done) : -1;
  auto report = [&](const std::string& stage, int phase, size_t done, size_t total, double fraction) {
    if (options.progress)
      options.progress({stage, phase, done, total, std::clamp(fraction, 0.0, 1.0), CodebookSizes::of(db.codebooks),
                        "", 0, 0, resumed_tile});
  };

  const auto t_resample = clock::now();
  report("resample", 0, 0, sample.texel_count(), 0.0);
  const ResampleOperator op(sample, s.grid, s.resample);
  const double operator_seconds = seconds_since(t_resample);

  double resample_seconds = 0;
  const TexelSource source = texel_source(sample, op, &resample_seconds);

  // Phase 3 elsewhere: hand the saved state over, then continue from the folder as a resumed run.
  const bool remote = checkpoints && options.remote_phase3;
  size_t phase3_from = 0;
  const size_t phase3_tiles = phase3_tile_count(sample.texel_count(), s.schedule, &phase3_from);
  std::optional<PhaseThreeState> remote_state;
  auto hand_over = [&](size_t tiles_done) {
    CheckpointFolder& folder = checkpoints->folder;
    PhaseThreeWork w;
    w.folder = folder.folder();
    w.fingerprint = folder.fingerprint();
    w.sample = &sample;
    w.config = options.config.json();
    w.material = name;
    w.input = checkpoints->input;
    w.tiles_done = tiles_done;
    w.tiles = phase3_tiles;
    w.p4_rows = folder.p4_rows();
    w.tile_texels = size_t(s.schedule.tile_texels);
    w.progress = [&](size_t done) {
      const size_t total = sample.texel_count() - phase3_from, texels = std::min(total, done * size_t(s.schedule.tile_texels));
      const double f = total ? double(texels) / double(total) : 1.0;
      report("phase3", 3, texels, total, kStageStart[3] + f * (kStageEnd[3] - kStageStart[3]));
    };
    options.remote_phase3(w);
    std::optional<SavedWork> saved = folder.load();
    if (!saved || !saved->phase3 || saved->phase3->tiles_done != phase3_tiles)
      throw Error("internal", "phase 3 of '" + name + "' elsewhere left " +
                                  std::to_string(saved && saved->phase3 ? saved->phase3->tiles_done : 0) + " of " +
                                  std::to_string(phase3_tiles) + " tiles in " + w.folder);
    db.codebooks = std::move(saved->codebooks);
    remote_state = std::move(saved->phase3);
  };
  if (remote && resume && resume->tiles_done < phase3_tiles) {
    hand_over(resume->tiles_done);
    resume = &*remote_state;
  }

  ScheduleCheckpoints saves;
  if (checkpoints) {
    saves.resume = resume;
    saves.save = [&](size_t tiles_done, const ScheduleResult& so_far, std::span<const uint32_t> tile) {
      if (tiles_done > 0) return checkpoints->folder.append_tile(tiles_done, db.codebooks, so_far, tile);
      const PhaseThreeState start{0, so_far};
      checkpoints->folder.save_state(checkpoints->input, db, checkpoints->first_new, &start);
      if (remote) throw StopSchedule{};
    };
  }
  const auto t_schedule = clock::now();
  auto schedule = [&] {
    return run_schedule(
        db.codebooks, sample.dynamic(), sample.width(), sample.height(), source, s.thresholds, s.similarity, s.schedule,
        [&](const ScheduleProgress& p) {
          const double f = p.total ? double(p.done) / double(p.total) : 1.0;
          if (p.refining)
            report("refine", 0, p.done, p.total, kStageEnd[2]);
          else
            report("phase" + std::to_string(p.phase), p.phase, p.done, p.total,
                   kStageStart[p.phase] + f * (kStageEnd[p.phase] - kStageStart[p.phase]));
        },
        options.cancelled, saves);
  };
  ScheduleResult result;
  try {
    result = schedule();
  } catch (const StopSchedule&) {
    hand_over(0);
    saves.resume = &*remote_state;
    result = schedule();
  }

  Material m;
  m.name = name;
  m.width = sample.width();
  m.height = sample.height();
  m.dynamic = sample.dynamic();
  m.raw_bytes = sample.raw_bytes();
  m.p6_index = result.p6_index;
  m.p6_scale = result.p6_scale;
  db.materials.push_back(std::move(m));
  // Children of rejected compositions and entries nothing reached any more cost bytes and searches.
  const ReclaimReport reclaimed = reclaim_unreachable(db);

  const ScheduleReport& r = result.report;
  nlohmann::json phases = nlohmann::json::array();
  for (int p = 0; p < 3; ++p)
    phases.push_back({{"phase", p + 1}, {"texels", r.texels[p]}, {"seconds", r.seconds[p]}, {"cpu_seconds", r.cpu_seconds[p]},
                      {"codebook_sizes", r.sizes[p]}});
  double mean_dissimilarity = 0, worst = 0;
  for (float d : result.dissimilarity) {
    mean_dissimilarity += d;
    worst = std::max(worst, double(d));
  }
  mean_dissimilarity /= double(std::max<size_t>(result.dissimilarity.size(), 1));
  CompressReport out;
  out.material = name;
  out.width = sample.width();
  out.height = sample.height();
  out.raw_bytes = sample.raw_bytes();
  out.json = {{"material", name},
              {"width", sample.width()},
              {"height", sample.height()},
              {"dynamic", sample.is_hdr() ? "HDR" : "LDR"},
              {"raw_bytes", sample.raw_bytes()},
              {"device", ComputeDevice::get().description()},
              {"phases", phases},
              {"seconds", {{"resample_operator", operator_seconds},
                           {"resample", resample_seconds},
                           {"schedule_total", seconds_since(t_schedule)}}},
              {"dissimilarity", {{"mean", mean_dissimilarity}, {"max", worst}}},
              {"refine", refine_json(r)},
              {"phase3_composition", {{"texels", r.composed}, {"propose_seconds", r.propose_seconds}, {"adopt_seconds", r.adopt_seconds}}},
              {"search", {{"path", r.search == SearchPath::Pruned          ? "pruned"
                                   : r.search == SearchPath::BatchedOpenCL ? "batched-opencl"
                                   : r.search == SearchPath::BatchedMSE    ? "batched-mse"
                                                                           : "batched-reference"},
                          {"scored", r.search_stats.scored},
                          {"settled", r.search_stats.settled},
                          {"batch_seconds", r.search_stats.batch_seconds},
                          {"settle_seconds", r.search_stats.settle_seconds}}},
              {"encoder", {{"comparisons", r.encoder.comparisons},
                           {"pruned", r.encoder.pruned},
                           {"fallbacks", r.encoder.fallbacks},
                           {"inserted", {{"search_miss", r.encoder.inserted_miss},
                                         {"retry", r.encoder.inserted_retry},
                                         {"exact", r.encoder.inserted_exact}}},
                           {"reused_identical", r.encoder.reused},
                           {"searched_ahead", {{"parts", r.encoder.ahead},
                                               {"extended", r.encoder.ahead_extended},
                                               {"redone", r.encoder.ahead_redone},
                                               {"rows", r.encoder.rows_ahead},
                                               {"rows_redone", r.encoder.rows_redone}}},
                           {"reclaimed", reclaimed.removed},
                           {"reachable", reclaimed.reachable}}},
              {"codebook_sizes", CodebookSizes::of(db.codebooks)}};
  if (resumed_tile >= 0) out.json["resumed_from_tile"] = resumed_tile;
  if (remote) out.json["phase3_tiles_elsewhere"] = phase3_tiles - size_t(std::max<int64_t>(resumed_tile, 0));
  report("done", 0, sample.texel_count(), sample.texel_count(), 1.0);
  return out;
}

}  // namespace

CompressReport compress_material(Database& db, const MeasuredSample& sample, const std::string& name,
                                 const CompressOptions& options) {
  return compress_one(db, sample, name, options, nullptr);
}

TilePart compute_tile_part(const std::string& snapshot, const std::string& sample_path, size_t first, size_t end,
                           const std::string& out) {
  namespace fs = std::filesystem;
  using clock = std::chrono::steady_clock;
  const auto t_load = clock::now();
  auto text = [](const fs::path& p) { return read_file(p.string(), " (is this a tile snapshot folder?)"); };
  const fs::path dir(snapshot);
  const ParameterDictionary config(nlohmann::json::parse(text(dir / "config.json")), (dir / "config.json").string());
  const PipelineSettings s = read_settings(config);
  ComputeDevice::configure(s.device);
  CheckpointFolder folder(snapshot, text(dir / "fingerprint"));
  std::optional<SavedWork> saved = folder.load();
  if (!saved || !saved->phase3) throw InputError("the snapshot " + snapshot + " holds no phase-3 state");
  const MeasuredSample sample = read_raw_sample(sample_path);
  const size_t tiles = phase3_tile_count(sample.texel_count(), s.schedule);
  if (first >= end || end > tiles)
    throw InputError("--tiles " + std::to_string(first) + "-" + std::to_string(end - 1) + ": the sample has phase-3 tiles 0-" +
                     std::to_string(tiles - 1));
  if (saved->phase3->tiles_done > first || saved->phase3->result.p6_index.size() != sample.texel_count())
    throw InputError("the snapshot " + snapshot + " is not of this sample or already past tile " + std::to_string(first));
  const ResampleOperator op(sample, s.grid, s.resample);
  double resample_seconds = 0;
  const TexelSource source = texel_source(sample, op, &resample_seconds);

  TilePart part;
  part.first = first;
  part.end = end;
  part.p4_from = folder.p4_rows();
  part.load_seconds = std::chrono::duration<double>(clock::now() - t_load).count();
  const std::string records = out + ".records-" + std::to_string(::getpid());
  std::error_code ec;
  fs::remove(records, ec);
  fs::remove(out + ".json", ec);
  folder.log_to(records);
  Codebooks books = std::move(saved->codebooks);
  PhaseThreeState start = std::move(*saved->phase3);
  start.tiles_done = first;  // speculative when the snapshot is older: the merge checks p4_from
  ScheduleCheckpoints saves;
  saves.resume = &start;
  const auto t0 = clock::now();
  auto t_tile = t0;
  saves.save = [&](size_t tiles_done, const ScheduleResult& so_far, std::span<const uint32_t> tile) {
    folder.append_tile(tiles_done, books, so_far, tile);
    const auto now = clock::now();
    part.tile_seconds.push_back(std::chrono::duration<double>(now - t_tile).count());
    t_tile = now;
    if (tiles_done >= end) throw StopSchedule{};
  };
  try {
    run_schedule(books, sample.dynamic(), sample.width(), sample.height(), source, s.thresholds, s.similarity,
                 s.schedule, {}, {}, saves);
  } catch (const StopSchedule&) {
  }
  part.seconds = std::chrono::duration<double>(clock::now() - t0).count();
  part.p4_end = books.p4_index.rows();
  const std::string bytes = text(records);
  part.bytes = bytes.size();
  part.sha256 = sha256_hex(bytes);
  fs::rename(records, out, ec);
  if (ec) throw InputError("cannot rename '" + records + "' to '" + out + "': " + ec.message());
  const nlohmann::json manifest = {{"first", part.first}, {"end", part.end}, {"p4_from", part.p4_from},
                                   {"p4_end", part.p4_end}, {"bytes", part.bytes}, {"sha256", part.sha256},
                                   {"load_seconds", part.load_seconds}, {"seconds", part.seconds},
                                   {"tile_seconds", part.tile_seconds}};
  write_file_atomically(out + ".json", manifest.dump(1));
  return part;
}

namespace {

std::vector<uint8_t> read_previous(const std::string& path) {
  if (path.empty() || !std::filesystem::exists(path)) return {};
  const std::string bytes = read_file(path, " (the database to add to)");
  return {bytes.begin(), bytes.end()};
}

// Share of one input's progress that loading takes (the rest is compress_material's own fraction).
constexpr double kLoadShare = 0.1;

// What a work folder's checkpoints are of: the same previous file, settings and inputs.
std::string work_fingerprint(const std::vector<uint8_t>& previous, const std::vector<MaterialInput>& inputs,
                             const CompressOptions& options) {
  nlohmann::json j = {{"checkpoint", 1},
                      {"previous", sha256_hex(std::string(previous.begin(), previous.end()))},
                      {"config", options.config.json()},
                      {"inputs", nlohmann::json::array()}};
  for (const MaterialInput& in : inputs) j["inputs"].push_back({in.name, in.identity});
  return sha256_hex(j.dump());
}

// A material that an interrupted call had finished: the report says only that.
CompressReport finished_earlier(const Material& m) {
  CompressReport r;
  r.material = m.name;
  r.width = m.width;
  r.height = m.height;
  r.raw_bytes = m.raw_bytes;
  r.json = {{"material", m.name}, {"width", m.width}, {"height", m.height}, {"raw_bytes", m.raw_bytes},
            {"resumed", "compressed before the interruption"}};
  return r;
}

}  // namespace

DatabaseSummary compress_database(const std::string& previous, const std::vector<MaterialInput>& inputs,
                                  const std::string& out, const CompressOptions& options) {
  validate_pipeline_config(options.config);
  const std::vector<uint8_t> previous_bytes = read_previous(previous);
  Database db = previous_bytes.empty() ? Database{} : parse_database(previous_bytes, previous);
  std::set<std::string> names;
  for (const MaterialInput& in : inputs) {
    check_material_name(in.name);
    if (db.find(in.name)) throw InputError("the database already has a material named '" + in.name + "'");
    if (!names.insert(in.name).second) throw InputError("two inputs are both named '" + in.name + "'");
  }

  const double n = double(std::max<size_t>(inputs.size(), 1));
  auto cancelled = [&] { return options.cancelled && options.cancelled(); };
  DatabaseSummary summary;
  std::optional<CheckpointFolder> folder;
  std::optional<SavedWork> saved;
  if (!options.checkpoint_folder.empty() && !options.target) {
    folder.emplace(options.checkpoint_folder, work_fingerprint(previous_bytes, inputs, options));
    saved = folder->load();
  }
  const size_t first_new = db.materials.size();
  size_t first_input = 0;
  if (saved) {  // the code-books only grew from the previous file's, and the fingerprint names that file
    db.codebooks = std::move(saved->codebooks);
    for (Material& m : saved->finished) {
      summary.added.push_back(finished_earlier(m));
      db.materials.push_back(std::move(m));
    }
    first_input = std::min(saved->input, inputs.size());
  }
  for (size_t i = first_input; i < inputs.size(); ++i) {
    const MaterialInput& in = inputs[i];
    auto forward = [&](CompressProgress p, double within) {
      p.fraction = (double(i) + within) / n;
      p.material = in.name;
      p.material_index = i;
      p.materials = inputs.size();
      if (options.progress) options.progress(p);
    };
    if (cancelled()) throw CancelledError();
    forward({in.load_stage, 0, 0, 0, 0, CodebookSizes::of(db.codebooks)}, 0);
    const auto t_load = std::chrono::steady_clock::now();
    const MeasuredSample sample = in.load([&](size_t done, size_t total) {
      forward({in.load_stage, 0, done, total, 0, CodebookSizes::of(db.codebooks)},
              total ? kLoadShare * double(done) / double(total) : 0);
    });
    const double load_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_load).count();
    if (cancelled()) throw CancelledError();
    CompressOptions o = options;
    o.progress = [&](const CompressProgress& p) { forward(p, kLoadShare + (1 - kLoadShare) * p.fraction); };
    if (options.target) {
      summary.added.push_back(compress_to_target(db, sample, in.name, *options.target, o));
      summary.added.back().json["seconds"]["load"] = load_seconds;
      continue;
    }
    const PhaseThreeState* resume = saved && saved->input == i && saved->phase3 ? &*saved->phase3 : nullptr;
    std::optional<MaterialCheckpoints> at;
    if (folder) at.emplace(MaterialCheckpoints{*folder, i, first_new, resume});
    summary.added.push_back(compress_one(db, sample, in.name, o, at ? &*at : nullptr));
    summary.added.back().json["seconds"]["load"] = load_seconds;
    if (folder) folder->save_state(i + 1, db, first_new, nullptr);
  }
  if (options.progress) options.progress({"write", 0, 0, 0, 1.0, CodebookSizes::of(db.codebooks), "", 0, inputs.size()});
  const auto t_write = std::chrono::steady_clock::now();
  // Round the new rows to what the file stores, so the in-memory model and the file decode alike.
  quantize_new_rows(db);
  const std::vector<uint8_t> bytes = serialize_database(db, {}, previous_bytes.empty() ? nullptr : &previous_bytes);
  write_file_atomically(out, bytes);
  summary.bytes = bytes.size();
  summary.raw_bytes = raw_bytes(db);
  summary.ratio = compression_ratio(summary.raw_bytes, summary.bytes);
  summary.materials = db.materials.size();
  summary.write_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_write).count();
  return summary;
}

}  // namespace btfvq
