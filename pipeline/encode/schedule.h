#pragma once
// Three-phase code-book generation (paper Sec. 5.1.1; docs/encoder.md):
//   phase 1: grow the code-books on the first ~1% of the texels in 2D Halton order, with the
//            configured thresholds;
//   phase 2: relax the thresholds (dissimilarity x 2.5) and grow them on the next ~4%;
//   phase 3: freeze the code-books and find, for every remaining texel, the best P4 entry and scale.
// Texels come from a TexelSource in tiles, so memory stays bounded by one tile.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "pipeline/codebook.h"
#include "pipeline/util/config.h"
#include "pipeline/encode/encoder.h"
#include "pipeline/encode/frozen_search.h"
#include "pipeline/encode/refine.h"

namespace btfvq {

// The "schedule" section of configs/pipeline.json (the members carry no values of their own).
struct ScheduleSettings {
  double phase1_fraction = 0;
  double phase2_fraction = 0;
  double relax_factor = 0;
  int tile_texels = 0;
  int threads = 0;  // phase 3 workers
  // Phase 3 search: "auto" (the fastest: the batched kernel on OpenCL, else pruned), "pruned",
  // "batched" (OpenCL, or its C++ reference without OpenCL), "batched-reference" (the kernel's C++
  // reference even on OpenCL: for comparisons). All give the same entries. Under assign_metric
  // "mse" every value but "pruned" is the closed-form batch (FrozenSearch, BatchedMSE).
  std::string search;
  // The similarity by which the refinement's assignment and phase 3 choose a texel's P4 entry and
  // judge a composition (the growing phases keep similarity.metric): MSE by default. The SSIM
  // percentile is a tail measure, good at deciding whether a code-book needs a new entry, but as
  // the choice among stored entries it keeps the worst 2 % of a texel's windows close at the cost of
  // the rest, which the images' MSSIM averages (docs/encoder.md "Assignment by MSE"). Its thresholds
  // (thresholds.<metric>, relaxed as phase 2's) bound the groups of compose_p3.
  Metric assign_metric = Metric::MSE;
  Thresholds assign_thresholds;
  // Phase-3 composition: a texel whose best stored P4 entry is farther than compose_threshold (a
  // dissimilarity of assign_metric: MSE in squared 8-bit units, SSIM in [0, 2]) gets a new P4 entry
  // of the best stored P3 entry per phi_v group when that is at least compose_gain closer
  // (Encoder::propose_p4); with compose_p3, a group whose best stored P3 entry misses the P3
  // threshold may get a new P3 entry of stored M entries as well, in the texels of an evenly spread
  // share compose_p3_share of the Halton order (so that the quality rule can switch it on gradually).
  double compose_threshold = 0;
  double compose_gain = 0;
  bool compose_p3 = false;
  double compose_p3_share = 1;
  // Lloyd refinement between the growing phases and phase 3 (the "refine" section; off when
  // refine.iterations is 0): phase 3 then assigns every texel, those of phases 1 and 2 included.
  RefineSettings refine;
  SearchPath search_path(const AngularGrid& grid, const SimilaritySettings& similarity) const;

  // Reads the "schedule" and "refine" sections.
  static ScheduleSettings from(const ParameterDictionary& d);
  static ScheduleSettings defaults();  // from(the shipped configs/pipeline.json)
};

struct ScheduleProgress {
  int phase = 1;  // 1, 2 or 3
  bool refining = false;  // between phases 2 and 3: done / total count refinement iterations
  size_t done = 0, total = 0;  // texels of this phase
  CodebookSizes sizes;
};

struct ScheduleReport {
  size_t texels[3] = {0, 0, 0};
  CodebookSizes sizes[3];   // after each phase
  double seconds[3] = {0, 0, 0};
  double cpu_seconds[3] = {0, 0, 0};  // the process's CPU time over the same stretches (every thread)
  EncoderStats encoder;     // phases 1 and 2
  SearchPath search = SearchPath::Pruned;  // phase 3
  SearchStats search_stats;
  size_t composed = 0;  // phase-3 texels given a new P4 entry (the entries: P4 after phase 3 - after phase 2)
  double propose_seconds = 0, adopt_seconds = 0;  // of phase 3's composition (parallel, in texel order)
  size_t refine_texels = 0;         // the texels the refinement fitted the entries to
  std::vector<RefineStep> refine;   // one per iteration
  double refine_seconds = 0;        // assignments and updates
};

struct ScheduleResult {
  std::vector<int32_t> p6_index;  // height x width, row-major
  std::vector<float> p6_scale;
  std::vector<float> dissimilarity;  // per texel, as the encoder measured it
  ScheduleReport report;
};

// What run_schedule needs, besides the code-books as they were then, to continue phase 3 after
// `tiles_done` of its tiles as if it had never stopped (pipeline/encode/checkpoint.h keeps it).
struct PhaseThreeState {
  size_t tiles_done = 0;
  ScheduleResult result;  // p6 rows of the tiles done (and of phases 1-2 without a refinement), report so far
};

// Checkpoints of one run_schedule call. `save` is called when phase 3 starts (tiles_done 0: the
// code-books are a finished version of the growing phases and the refinement) and after each
// phase-3 tile, with the texels that tile assigned; it may throw to stop the run (a full disk).
struct ScheduleCheckpoints {
  std::function<void(size_t tiles_done, const ScheduleResult& so_far, std::span<const uint32_t> tile)> save;
  const PhaseThreeState* resume = nullptr;  // continue from here (the code-books already restored)
};

// Every texel of a width x height grid exactly once, in the order of the 2D Halton sequence
// (bases 2 and 3); texels the sequence has not reached after 16 x W x H points follow in scan order.
std::vector<uint32_t> halton_order(int width, int height);

// Number of texels in phases 1 and 2 (at least one in phase 1).
void phase_sizes(size_t texels, const ScheduleSettings& s, size_t* phase1, size_t* phase2);

// Number of phase-3 tiles run_schedule makes of `texels` (every texel with a refinement, else those
// after phases 1 and 2, in tiles of tile_texels): what a checkpoint's tiles_done counts to.
// `first_texel`: where phase 3 starts in Halton order.
size_t phase3_tile_count(size_t texels, const ScheduleSettings& s, size_t* first_texel = nullptr);

ScheduleResult run_schedule(Codebooks& books, Dynamic dyn, int width, int height, const TexelSource& source,
                            const Thresholds& thresholds, const SimilaritySettings& similarity,
                            const ScheduleSettings& schedule,
                            const std::function<void(const ScheduleProgress&)>& progress = {},
                            const std::function<bool()>& cancelled = {},
                            const ScheduleCheckpoints& checkpoints = {});

}  // namespace btfvq
