#pragma once
// The seam between the job queue and the compressor. The service owns scheduling, version numbers
// and publication; an Executor only turns a job's materials (plus the previous version of the
// target database, if any) into a complete database file at `output_path`. The real executor
// (pipeline_executor.cpp) calls compress_material(); tests plug in small lambdas.
#include <nlohmann/json.hpp>

#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "pipeline/codebook.h"
#include "pipeline/metrics/btf_cielab.h"

namespace btfvq {
struct PhaseThreeWork;  // pipeline/encode/tile_parts.h
}

namespace btfvq::server {

// One material of a job, with its source already validated and resolved by the service.
struct MaterialSpec {
  std::string name;
  std::string kind;          // "upload", "path" or "synthetic"
  std::string upload_id;     // kind == "upload"
  std::string file;          // kind == "upload" or "path": an existing file or directory on this machine
  std::string preset;        // kind == "synthetic"
  int size = 0;              //   texels per side
  int64_t seed = 0;
};

struct JobSpec {
  std::string id;
  std::string database;
  std::vector<MaterialSpec> materials;
  nlohmann::json pipeline = nlohmann::json::object();  // overrides of configs/pipeline.json
  double target_mssim = 0;       // > 0: search the quality that reaches it (pipeline/encode/target.h)
  double target_btf_cielab = 0;  // > 0: the same for a BTF-CIELab mean at most this
  // Set: each added material's report gains "btf_cielab", its BTF-CIELab (pipeline/metrics/btf_cielab.h)
  // against its sample at this viewing condition, decoded from the file the job publishes.
  std::optional<ViewingCondition> btf_cielab;
};

// What a running job reports; the service derives elapsed time and ETA from it.
struct JobProgress {
  std::string stage;          // "load", "resample", "phase1", "phase2", "refine", "phase3", "write", "btf_cielab", ...
  int phase = 0;              // 1, 2, 3 during the three-phase schedule; 0 otherwise
  double fraction = 0;        // of the whole job, 0..1
  uint64_t texels_done = 0;   // within the current stage
  uint64_t texels_total = 0;
  CodebookSizes codebook_sizes;
  std::string material;       // the material being compressed
  int64_t resumed_tile = -1;  // >= 0: the material continued from a checkpoint after this many phase-3 tiles
  std::string attempt;        // a target's search: which compression runs (CompressProgress::attempt)
};

// One material that the job added, as recorded in the catalogue (ratios are computed from these).
struct MaterialRecord {
  std::string name;
  uint64_t raw_bytes = 0;  // W*H*views*lights*3 (LDR) of the input
  int width = 0, height = 0;
  nlohmann::json report = nlohmann::json::object();  // the compressor's report
};

// Handed to the executor for the duration of one job. Callbacks are safe to call from any thread.
struct JobContext {
  std::function<void(const JobProgress&)> progress;  // never empty
  std::function<bool()> cancelled;                   // never empty; true -> throw CancelledError
  std::vector<MaterialRecord> added;                 // the executor appends one per material it added
  // Materials already in the previous version (so an executor can reject name clashes early).
  std::vector<std::string> existing_materials;
  uint64_t max_expanded_bytes = 0;                   // zip-bomb limit for archive inputs
  // The job's own folder for checkpoints: a job re-queued after a crash continues from what is
  // there. The queue removes it when the job ends.
  std::string work_folder;
};

// Writes a complete database (the previous one, if any, plus the job's materials) to
// `output_path`, the file of the version the job will publish, atomically (AtomicFile,
// pipeline/util/atomic_file.h): whether the executor returns or throws, the file there is complete
// or absent, because the service hashes and records it as it is. Throws btfvq::Error subclasses
// (InputError -> job failed with that message, CancelledError -> job cancelled).
using Executor = std::function<void(const JobSpec&, const std::string& previous_db_path_or_empty,
                                    const std::string& output_path, JobContext&)>;

// Phase 3 of one material done elsewhere (CompressOptions::remote_phase3): the Slurm executor.
using RemotePhaseThree = std::function<void(const JobSpec&, JobContext&, const PhaseThreeWork&)>;

// The real executor (server/pipeline_executor.cpp once the pipeline links); with `remote`, phase 3
// of every material is handed to it (jobs with a target MSSIM take no checkpoints and stay local).
Executor make_pipeline_executor(RemotePhaseThree remote = {});

// Submit-time checks that need the pipeline (pipeline_hooks.cpp).
// Throws ConfigError/InputError naming the key when `overrides` is not acceptable.
void validate_pipeline_overrides(const nlohmann::json& overrides);
// The synthetic presets that exist (for 400 on an unknown preset).
std::vector<std::string> synthetic_presets();

}  // namespace btfvq::server
