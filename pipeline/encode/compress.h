#pragma once
// The one call that compresses a measured sample into a database: resample in tiles, run the
// three-phase schedule, append the material. Shells (client/, server/) call only this.
#include <nlohmann/json.hpp>

#include <functional>
#include <string>

#include "pipeline/btf.h"
#include "pipeline/codebook.h"
#include "pipeline/util/config.h"
#include "pipeline/encode/schedule.h"

namespace btfvq {

struct CompressProgress {
  std::string stage;        // "resample", "phase1", "phase2", "phase3", "write"
  int phase = 0;            // 1, 2, 3 during the schedule; 0 otherwise
  size_t texels_done = 0;   // within the current stage
  size_t texels_total = 0;
  double fraction = 0;      // of the whole compression, 0..1
  CodebookSizes sizes{};
};

struct CompressOptions {
  ParameterDictionary config = ParameterDictionary::embedded_default("pipeline");
  std::function<void(const CompressProgress&)> progress;  // may be empty; called from worker threads
  std::function<bool()> cancelled;                         // polled between tiles; true -> CancelledError
};

struct CompressReport {
  std::string material;
  nlohmann::json json;  // texels per phase, code-book sizes after each phase, seconds per stage
};

// Reads and validates every pipeline setting of `config` (unknown keys are errors) without
// compressing anything: what a server checks when a job is submitted. Throws ConfigError.
void validate_pipeline_config(const ParameterDictionary& config);

// Compresses `sample` as material `name` into `db`: shared code-books grow (append-only), one
// material is appended. Throws InputError for a bad sample, name clash or bad config (before any
// change to `db`), CancelledError. After a CancelledError or a failure during encoding the
// code-books may have grown: discard `db` (the file on disk is only replaced after success).
CompressReport compress_material(Database& db, const MeasuredSample& sample, const std::string& name,
                                 const CompressOptions& options);

}  // namespace btfvq
