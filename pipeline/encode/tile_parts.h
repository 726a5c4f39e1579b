#pragma once
// Phase 3 on other machines (`btfvq tile`, the server's Slurm executor; docs/cluster.md).
//
// Phase-3 tiles are not independent: a tile's composition appends P4 rows (and, with
// schedule.compose_p3, the P3 rows they are made of) that the search of every later tile sees
// (Encoder::adopt_p4, FrozenSearch::sync). A new P3 row always comes with a new P4 row, so the
// P4 row count alone tells whether a tile appended anything. A tile is a pure function of (the
// code-books as of its start, its texels), and those code-books differ from the grown version
// exactly by the P4 rows earlier tiles appended. So a range of tiles computed elsewhere from a
// snapshot of the checkpoint (state.ckpt + tiles.log after T tiles) is the sequential result when
// the P4 rows as of its first tile are the snapshot's, i.e. when no tile between T and its first
// tile appended one. The merge appends the parts in tile order and checks exactly that
// (`p4_from`); a part computed from code-books that have since grown is computed again from a newer
// snapshot. The merged log is the tiles.log an uninterrupted local run would have written, and the
// input continues from it as a resumed one does: the database is byte-identical.
//
// A part is the tiles.log records of its tiles (CheckpointFolder::append_tile, redirected) plus a
// manifest PART.json written after it (tile range, P4 rows before and after, bytes, SHA-256).
#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>

#include <nlohmann/json.hpp>

#include "pipeline/btf.h"

namespace btfvq {

// What CompressOptions::remote_phase3 is handed when an input's phase 3 starts (or continues after
// a restart): the checkpoint folder holds state.ckpt and tiles.log as of `tiles_done` tiles.
struct PhaseThreeWork {
  std::string folder, fingerprint;  // the checkpoint folder and its work's fingerprint
  const MeasuredSample* sample = nullptr;
  nlohmann::json config;            // the pipeline configuration (every key)
  std::string material;
  size_t input = 0;                 // position among the call's inputs
  size_t tiles_done = 0, tiles = 0;  // phase-3 tiles in the folder's log, in all
  size_t p4_rows = 0;               // P4 rows of the code-books the folder holds
  size_t tile_texels = 0;
  std::function<void(size_t tiles_done)> progress;  // maps onto the call's progress (stage "phase3")
};

// A folder `btfvq tile` computes from: state.ckpt and tiles.log copied from the work's folder,
// config.json and the fingerprint. Returns the P4 rows it holds.
size_t write_tile_snapshot(const PhaseThreeWork& work, const std::string& dir);

// The sample exactly as it is in memory (the texels must be those of the local run, so no JPEG):
// "BTFVQSM1", width, height, dynamic, the views and light lists, the values.
void write_raw_sample(const MeasuredSample& sample, const std::string& path);
MeasuredSample read_raw_sample(const std::string& path);

struct TilePart {
  size_t first = 0, end = 0;       // phase-3 tiles [first, end), numbered from 0
  size_t p4_from = 0, p4_end = 0;  // P4 rows the part started from and ended with
  uint64_t bytes = 0;              // of the records
  std::string sha256;              // of the records
  double load_seconds = 0, seconds = 0;  // loading (snapshot, sample, resampling operator); the tiles
  nlohmann::json tile_seconds = nlohmann::json::array();  // per tile
};

// `btfvq tile`: tiles [first, end) of the snapshot's input from the snapshot's code-books (the
// snapshot holds at most `first` tiles), written to `out` and then `out`.json.
TilePart compute_tile_part(const std::string& snapshot, const std::string& sample, size_t first, size_t end,
                           const std::string& out);

// The manifest of a finished part, checked against its records: byte count, SHA-256, one record per
// tile with consecutive tile numbers. Throws CorruptError (or InputError when there is none yet).
TilePart check_tile_part(const std::string& out);

// Appends a checked part's records to the work folder's tiles.log (durably).
void merge_tile_part(const PhaseThreeWork& work, const std::string& out);

}  // namespace btfvq
