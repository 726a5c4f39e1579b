#pragma once
// Refinement of the code-books a compression adds (Lloyd / LBG, docs/encoder.md "Refinement").
//
// The growing phases make an entry of the first slice that missed: it is the centre of nothing. With
// every texel's P6 entry known, each added entry is moved to the least-squares centre of the slices
// that reach it, through the chain of scales above them, and each added scale is refitted:
//
//   luminance   Y - o = S (ps d_b - o)      S = s6 s4 s3: P1 rows d and P2 scales ps, alternately
//   chroma      C - o = S (c - o)  (LDR)    C entries c, then each I1 row's C index (nearest centre)
//   planes      x - o = s6 s4 s3 (L - o)    P3, P4 and P6 scales, one block after the other
//
// Every update but the merges (RefineMerge) is the exact minimizer of the squared coding-space error
// with the rest fixed, so without merges the error never grows; a merge trades a bounded error for
// a row. Only rows at or past `first` move (published rows, and rows of materials
// compressed before, stay byte for byte), and only through texels of this material, which are the
// only ones that reach them. Sums are taken on one thread in texel order: the result does not depend
// on the device or the thread count.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <future>
#include <vector>

#include "pipeline/codebook.h"
#include "pipeline/util/config.h"

namespace btfvq {

// Added rows that the refinement merges, by how far apart they may be: a row's radius is this
// at the mean weight (the squared error per unit distance^2) and shrinks as 1/sqrt(weight), so a
// merge costs at most radius^2 x mean weight. 0: none merge.
struct RefineMerge {
  double p1 = 0;  // P1 densities (Euclidean over n_beta values)
  double p2 = 0;  // P2 slices (Euclidean over n_alpha x n_beta luminance values)
  double i1 = 0;  // I1 rows (over their n_beta decoded (a, b) pairs)
  double i2 = 0;  // I2 slices (over n_alpha x n_beta decoded (a, b) pairs)
  // The error the merges of one kind of row may add together, as a fraction of the texels'
  // squared error before the step; the cheapest merges are kept. The radii say which rows are
  // alike; this says how much of the material's own error a merge may cost, so a material coded
  // near its noise floor merges less than one coded coarsely.
  double budget = 1e300;
};

// Which row each row merges into (the refinement's merges; rows: n x dim values, weight: n).
// Rows are taken heaviest first; a row joins the nearest leader within its reach, radius^2 x mean
// weight / its weight (the error a merge adds is the row's weight times the squared distance, so
// heavy rows merge only when close, light ones readily), else it leads; of leaders equally near,
// the one that led first. Rows of weight 0 (no texel reaches them) stay themselves. Of the merges
// found, the cheapest are kept while their added error stays within `budget`; the rest stay
// themselves (a follower leads nobody, so dropping its merge changes no other row's). `threads` as
// ParallelOptions::threads; the result does not depend on it.
std::vector<uint32_t> merge_leaders(const std::vector<float>& rows, size_t dim, const std::vector<double>& weight,
                                    double radius, double budget, size_t threads = 0);

// The "refine" section of configs/pipeline.json.
struct RefineSettings {
  int iterations = 0;    // Lloyd iterations (assign, update) at most; 0: no refinement
  double fraction = 0;   // of the texels, a prefix of the Halton order, that the entries are fitted to
  double min_gain = 0;   // stop once an iteration lowers the error by less than this fraction
  RefineMerge merge;     // in the first iteration

  static RefineSettings from(const ParameterDictionary& d);
};

// Resamples the given texels (ids y * width + x) into out (n x 3 x grid.samples() floats).
using TexelSource = std::function<void(const uint32_t* texel_ids, size_t n, float* out)>;

// Resamples tiles ahead of their use: fetch() starts the source on another thread into one of two
// buffers, take() waits for that fetch and returns its texels (n x `values` floats), which stay
// valid until the fetch after the next. One source call at a time and in order (take() before the
// next fetch()), so memory holds two tiles; the source's error comes out of take().
class TilePrefetch {
 public:
  TilePrefetch(const TexelSource& source, size_t values) : source_(source), values_(values) {}
  void fetch(const uint32_t* ids, size_t n);
  const float* take();

 private:
  const TexelSource& source_;
  size_t values_;
  std::vector<float> buffers_[2];
  int filling_ = 1;  // the buffer of the last fetch
  // Declared after the buffers: destroyed first, it waits for a fetch in flight before they go.
  std::future<void> pending_;
};

// Calls f(at, n, x) for the tiles of `tile` texels of ids[0, count) in order, x the n texels
// resampled (n x `values` floats); the next tile is resampled meanwhile (TilePrefetch). An error of
// f or of the source ends it.
void for_each_tile(const uint32_t* ids, size_t count, const TexelSource& source, size_t tile, size_t values,
                   const std::function<void(size_t at, size_t n, const float* x)>& f);

// Texels and what they are encoded as: P4 entry and P6 scale per id.
struct Assignment {
  std::vector<uint32_t> ids;
  std::vector<uint32_t> p4;
  std::vector<float> scale;
};

struct RefineStep {
  double mse_before = 0, mse_after = 0;  // per value, coding space, over the assignment's texels
};

// The assignment step of a Lloyd iteration for one tile: sets the P4 entries and scales (n each)
// of the n texels x (n x 3 x grid.samples() floats) with the code-books as they are.
using AssignTile = std::function<void(const float* x, size_t n, uint32_t* p4, float* scale)>;

// One update of the rows at or past `first` (and of the assignment's scales) for the assignment.
// Texels come from `source` in tiles of `tile` texels. With `assign`, each tile is assigned first,
// in the same pass as the first sums (the texels are resampled once for both); the assignment's P4
// entries and scales are then only its output. The rows `merge` makes redundant are left for
// reclaim_unreachable(). `threads` as ParallelOptions::threads; the result does not depend on it.
RefineStep refine_step(Codebooks& books, const CodebookSizes& first, Dynamic dyn, Assignment& assignment,
                       const TexelSource& source, size_t tile, const RefineMerge& merge = {}, size_t threads = 0,
                       const AssignTile& assign = {});

}  // namespace btfvq
