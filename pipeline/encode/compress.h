#pragma once
// The calls that compress measured samples into a database, in the manner of OpenImageIO's
// make_texture: the shells (client/ `btfvq compress`, the server's job executor) turn their flags or
// job fields into options, make one compress_database() call, and only map its progress.
//
//   compress_database:  previous file -> check names -> per input: load, compress_material
//                       -> quantize -> serialize (old sections byte for byte) -> atomic write
//   compress_material:  one sample into an in-memory database: resample in tiles, run the
//                       three-phase schedule, append the material.
#include <nlohmann/json.hpp>

#include <functional>
#include <optional>
#include <string>

#include "pipeline/btf.h"
#include "pipeline/codebook.h"
#include "pipeline/util/config.h"
#include "pipeline/encode/schedule.h"
#include "pipeline/encode/tile_parts.h"
#include "pipeline/metrics/btf_cielab.h"

namespace btfvq {

struct CompressProgress {
  std::string stage;        // "load", "resample", "phase1", "phase2", "refine", "phase3", "done", then "write"
  int phase = 0;            // 1, 2, 3 during the schedule; 0 otherwise
  size_t texels_done = 0;   // within the current stage (images during "load", iterations during "refine")
  size_t texels_total = 0;
  double fraction = 0;      // compress_material: of this material; compress_database: of the whole call; 0..1
  CodebookSizes sizes{};
  std::string material;     // compress_database: the input being worked on ("" while writing)
  size_t material_index = 0, materials = 0;
  int64_t resumed_tile = -1;  // this material continues from a checkpoint after this many phase-3 tiles
  // Target mode: which compression of the search runs, at which setting, and what the one before
  // gave ("attempt 2: quality 90 on 24 view azimuths; attempt 1 gave MSSIM 0.5225 at 49,067 B").
  std::string attempt;
};

// Target mode (pipeline/encode/target.h): the quality knob searched until a metric of the whole
// sample reaches a value. MSSIM rises with quality, the BTF-CIELab mean falls: the search knows the
// direction, so a target is "at least" for the one and "at most" for the other.
enum class TargetMetric { Mssim, BtfCielab };
struct QualityTarget {
  TargetMetric metric = TargetMetric::Mssim;
  double value = 0;              // MSSIM in (0, 1), or a BTF-CIELab mean > 0 (CIEDE2000 units)
  ViewingCondition condition;    // of the BTF-CIELab target
  nlohmann::json overrides;      // the user's settings, over the knob (with_quality)
  int max_attempts = 4;          // whole compressions at most
  // Stop once the target is passed by at most this much, in the metric's units; unset: the metric's
  // own (target.h).
  std::optional<double> tolerance;
};

struct CompressOptions {
  ParameterDictionary config = ParameterDictionary::embedded_default("pipeline");
  std::optional<QualityTarget> target;  // set: `config` is ignored for the settings the knob sets
  std::function<void(const CompressProgress&)> progress;  // may be empty; called from worker threads
  std::function<bool()> cancelled;                         // polled between tiles; true -> CancelledError
  // A work folder (pipeline/encode/checkpoint.h): checkpoints go there, and a call that finds the
  // checkpoints of the same work (inputs, settings, previous file) continues from them. The caller
  // removes them (remove_checkpoints) once the database is where it belongs. Not with `target`.
  std::string checkpoint_folder;
  // Phase 3 elsewhere (the server's Slurm executor, docs/cluster.md): called, with a checkpoint
  // folder, once an input's phase-3 state is saved there; it returns when the folder's tiles.log
  // holds every phase-3 tile of the input, which then continues from the checkpoint as a resumed
  // one does (the same bytes as a local phase 3). May throw (CancelledError, ...).
  std::function<void(const PhaseThreeWork&)> remote_phase3;
};

struct CompressReport {
  std::string material;
  int width = 0, height = 0;
  uint64_t raw_bytes = 0;
  nlohmann::json json;  // texels per phase, code-book sizes after each phase, seconds per stage
};

// Reads and validates every pipeline setting of `config` (unknown keys are errors) without
// compressing anything. Throws ConfigError.
void validate_pipeline_config(const ParameterDictionary& config);

// The shipped defaults (configs/pipeline.json) with `overrides` merged on top, validated: every key
// must exist in the defaults with the same JSON type, and the merged settings must pass
// validate_pipeline_config. The one check of user settings, for `--config` files and job fields
// alike; a mistake is a ConfigError naming the key and `origin`.
ParameterDictionary pipeline_config(const nlohmann::json& overrides, const std::string& origin);

// Compresses `sample` as material `name` into `db`: shared code-books grow (append-only), one
// material is appended. Throws InputError for a bad sample, name clash or bad config (before any
// change to `db`), CancelledError. After a CancelledError or a failure during encoding the
// code-books may have grown: discard `db` (the file on disk is only replaced after success).
CompressReport compress_material(Database& db, const MeasuredSample& sample, const std::string& name,
                                 const CompressOptions& options);

// One material to add: its name and how to load its sample. load() is called when the input's turn
// comes, so that one sample at a time is in memory; it reports (done, total) images.
struct MaterialInput {
  std::string name;
  std::string load_stage = "load";  // the progress stage while load() runs (e.g. "synthesize")
  std::function<MeasuredSample(const std::function<void(size_t, size_t)>& progress)> load;
  // What the input is, for the checkpoints' fingerprint (e.g. a path with its size and time, or a
  // preset with its seed): a different input under the same name is not resumed.
  std::string identity;
};

struct DatabaseSummary {
  uint64_t bytes = 0;      // of the written file
  uint64_t raw_bytes = 0;  // of every material's measured input (the old ones included)
  double ratio = 0;        // compression_ratio(raw_bytes, bytes)
  size_t materials = 0;    // in the database now
  double write_seconds = 0;  // quantizing the new rows, serializing (entropy coding) and writing
  std::vector<CompressReport> added;  // one per input, in order
};

// Compresses `inputs` into the database at `previous` ("" or a path that does not exist: a new
// database) and writes the result to `out` atomically (`out` may equal `previous`). Sections
// the previous file already holds are copied from it byte for byte. Names are checked (valid,
// unique, not in the previous database) before any work; InputError / ConfigError /
// CancelledError leave `out` as it was. `options.progress` sees every stage of every input with
// `fraction` over the whole call (loading is the first tenth of each input's share).
DatabaseSummary compress_database(const std::string& previous, const std::vector<MaterialInput>& inputs,
                                  const std::string& out, const CompressOptions& options);

}  // namespace btfvq
