#pragma once
// Checkpoints of compress_database (docs/encoder.md "Checkpoints"): a killed compression continues
// from its last completed phase-3 tile and writes the same bytes as an uninterrupted one.
//
// A work folder holds two files:
//   state.ckpt  the work's fingerprint, the input in progress, the code-books (unquantized, exact),
//               the materials finished so far and, once phase 3 has started, its PhaseThreeState;
//               rewritten (atomically) when phase 3 of an input starts and when an input is done;
//   tiles.log   one record per phase-3 tile after that: the P4 rows the tile composed (and the P3
//               rows, with schedule.compose_p3) and the P6 rows it assigned, each record with its own
//               SHA-256 and the state's generation, so that a record torn by the kill, or left from
//               an older state, is ignored.
// Phase 3 adds only P4 and P3 rows (Encoder::adopt_p4), so a tile record is a few kilobytes.
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "pipeline/codebook.h"
#include "pipeline/encode/schedule.h"

namespace btfvq {

// What an earlier, interrupted call left.
struct SavedWork {
  size_t input = 0;                // the input in progress (inputs before it are finished)
  Codebooks codebooks;             // as they were at the checkpoint
  std::vector<Material> finished;  // materials this work added, in order
  std::optional<PhaseThreeState> phase3;  // of `input`, when its phase 3 had started
};

class CheckpointFolder {
 public:
  // `fingerprint` names the work (inputs, settings, previous file): a folder holding another
  // work's checkpoint is not resumed from (and is overwritten by this work's first checkpoint).
  CheckpointFolder(std::string folder, std::string fingerprint);

  const std::string& folder() const { return folder_; }
  const std::string& fingerprint() const { return fingerprint_; }
  // P4 rows the state plus the log hold (after load() or save_state(); append_tile adds to it).
  size_t p4_rows() const { return logged_[CodebookId::P4]; }

  // The saved work, or nothing when the folder is empty, damaged or of another fingerprint (said
  // in one log line). A torn last tile record is dropped; the log continues after the last good one.
  std::optional<SavedWork> load();

  // A new state: `input` in progress, the code-books, the materials of this work so far (those of
  // db.materials from `first_new` on) and phase 3's state (nullptr: phase 3 not started yet).
  void save_state(size_t input, const Database& db, size_t first_new, const PhaseThreeState* phase3);
  // One more phase-3 tile of the state's input: `tiles_done` in all, the code-books now, the P6 rows
  // of `tile`'s texels in `so_far`.
  void append_tile(size_t tiles_done, const Codebooks& books, const ScheduleResult& so_far,
                   std::span<const uint32_t> tile);
  // Later append_tile records go to `path` instead of the folder's tiles.log (a phase-3 tile part
  // computed on another node, pipeline/encode/tile_parts.h): the same bytes, the same generation.
  void log_to(std::string path) { log_override_ = std::move(path); }
  // Appends records written by append_tile elsewhere (a checked tile part) to the folder's tiles.log,
  // durably; load() replays them like its own.
  void append_records(const std::string& bytes);

 private:
  std::string state_path() const;
  std::string log_path() const;

  std::string folder_, fingerprint_;
  std::string log_override_;   // log_to()
  uint64_t generation_ = 0;    // of the state the log continues
  CodebookSizes logged_{};     // code-book rows the state plus the log hold
};

// Removes a work folder's checkpoint files (and the folder when it is then empty): after the
// database they were for is written or published.
void remove_checkpoints(const std::string& folder);

}  // namespace btfvq
