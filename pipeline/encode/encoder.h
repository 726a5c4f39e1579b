#pragma once
// The multi-level vector quantizer (paper Sec. 4.2-4.3, Fig. 3; docs/encoder.md).
//
// Top-down per texel: the whole F_x is matched against P4 (with its best scale); failing that it is
// split into n_phi_v 3D slices matched against P3, each of those into n_theta_v 2D slices matched
// against M, and each 2D slice into its luminance (P2, then P1 rows) and chroma (I2, then I1 rows,
// then C) parts. A vector whose nearest code-vector is not within its threshold is inserted
// (pruning VQ), bottom-up, and indices and scales are returned upward. Code-books only grow.
//
// Scale semantics (the decoder's, docs/btfbase-format.md / eq. 4): P2 slices are absolute luminance of the
// normalized 2D slice, P1 rows are densities whose P2 scale is the row sum; C/I1/I2 chroma is
// absolute; the P3, P4 and P6 scales multiply RGB, i.e. (Y-16, Cb-128, Cr-128) for LDR and Y alone
// for HDR. New M, P3 and P4 entries are normalized to a fixed brightness so that slices of one shape
// but different brightness share entries.
#include <cstddef>
#include <cstdint>
#include <unordered_map>
#include <vector>

#include "pipeline/codebook.h"
#include "pipeline/util/config.h"
#include "pipeline/encode/proxy_index.h"
#include "pipeline/encode/signature_table.h"
#include "pipeline/encode/similarity.h"

namespace btfvq {

// Acceptance thresholds per code-book, as dissimilarities (SSIM: 1 - 2nd percentile of SSIM;
// MSE: mean squared error in coding-space units). C is a plain Euclidean (a, b) distance. Values
// come from the "thresholds" section of configs/pipeline.json only (the members carry none).
struct Thresholds {
  double p4 = 0, p3 = 0, m = 0, p2 = 0, p1 = 0, i2 = 0, i1 = 0, c = 0;

  // Reads "thresholds.ssim.*" and "thresholds.mse.*" (both are validated) and returns the set of
  // the given metric.
  static Thresholds from(const ParameterDictionary& d, Metric metric);
  // The same, for the metric named by "similarity.metric".
  static Thresholds from(const ParameterDictionary& d);
  // The shipped thresholds of `metric` (configs/pipeline.json).
  static Thresholds defaults(Metric metric = Metric::SSIM);
  // Every dissimilarity times factor (phase 2 of the schedule uses 2.5).
  Thresholds relaxed(double factor) const;
};

// The result for one texel: P6 entry (index into P4, scale) and how well it fits.
struct P6Entry {
  uint32_t index = 0;
  float scale = 1.0f;
  double dissimilarity = 0;  // of the texel and its reconstruction, per the similarity settings
};

struct EncoderStats {
  uint64_t texels = 0;
  uint64_t comparisons = 0;  // candidate evaluations started
  uint64_t pruned = 0;       // of which abandoned early
  uint64_t fallbacks = 0;    // new entries re-encoded exactly because their composition missed
  uint64_t laesa_skipped = 0;  // P4 candidates excluded by the MSE pivot bound (of `pruned`)
  // Composition parts searched ahead of their turn on two threads (Encoder::speculate), of which
  // the entries inserted meanwhile were scored on top (extended) or the search made again (redone).
  uint64_t ahead = 0, ahead_extended = 0, ahead_redone = 0;
  // P1 and I1 rows of a plane searched ahead (Encoder::rows_ahead), of which searched again because
  // a row before them inserted.
  uint64_t rows_ahead = 0, rows_redone = 0;
  // New rows per code-book by cause: a search miss whose composition matched at once, one inserted
  // while re-encoding a composition that missed its parent's threshold (retry), or an exact one.
  CodebookSizes inserted_miss, inserted_retry, inserted_exact;
  CodebookSizes reused;  // insertions that found the very same row stored already
  void add(const EncoderStats& o);
};

// What the batched phase-3 search needs of one texel, computed once: its values with luminance
// clamped at black (3 x grid.samples(), layout [channel][AngularGrid::index]), its SSIM constants per
// channel, the window means and variances of every plane and channel (plane-major, [mean | var] of
// n_alpha x n_beta each), and the P4 candidates encode_frozen() evaluates, in its order (the best by
// proxy; every entry when candidate_limit is 0).
struct FrozenQuery {
  std::vector<float> texel;
  float c1[3] = {0, 0, 0}, c2[3] = {0, 0, 0};
  std::vector<float> stats;
  std::vector<uint32_t> candidates;
};

// Brightness to which new M, P3 and P4 entries are normalized: mean of (Y - 16) for LDR, of Y for HDR.
float normalized_brightness(Dynamic dyn);

// A phase-3 texel's own P4 entry before it is stored (Encoder::propose_p4).
struct P4Proposal {
  // A group's P3 index at or above kNewP3 names new P3 row (index - kNewP3) of `new_m`/`new_scale`
  // (n_theta_v M indices and scales each): composed from the frozen M entries, stored by adopt_p4.
  static constexpr uint32_t kNewP3 = 0x80000000u;
  std::vector<uint32_t> p3;  // per phi_v group
  std::vector<float> scale;
  std::vector<uint32_t> new_m;
  std::vector<float> new_scale;
  P6Entry entry;             // index unset until adopted
  bool is_new(size_t group) const { return p3[group] >= kNewP3; }
};

class Encoder {
 public:
  Encoder(Codebooks& books, Dynamic dyn, const Thresholds& thresholds, const SimilaritySettings& settings);

  void set_thresholds(const Thresholds& t) { thresholds_ = t; }
  // Threads the P4 and P3 searches of the growing phases spread their candidates over (the result
  // does not depend on it); 1 by default.
  void set_threads(size_t n) { threads_ = n > 0 ? n : 1; }
  const Thresholds& thresholds() const { return thresholds_; }
  const SimilaritySettings& settings() const { return settings_; }
  const Codebooks& codebooks() const { return books_; }
  Dynamic dynamic() const { return dyn_; }
  const EncoderStats& stats() const { return stats_; }

  // Phases 1 and 2: encodes texel (3 x grid.samples() coding-space floats), growing the code-books.
  P6Entry encode_growing(const float* texel);
  // Phase 3: the best P4 entry and its scale; no insertion. Throws InputError if P4 is empty.
  // Thread-safe (const) as long as nobody grows the code-books at the same time.
  P6Entry encode_frozen(const float* texel) const;

  // Phase-3 composition, in two steps so that the search runs in parallel and the code-books grow in
  // texel order: a P4 entry made of the best stored P3 entry of every phi_v group, with the texel's
  // scale and dissimilarity; false if a group has no candidate. With compose_p3, a group whose best
  // P3 entry misses the P3 threshold gets a new P3 entry of the best stored M entry of each theta_v
  // slice when that fits it better (nothing below P3 is added). Thread-safe (const): it reads P3 and
  // below, which only adopt_p4 changes.
  bool propose_p4(const float* texel, P4Proposal* out, bool compose_p3 = false) const;
  // Stores the proposal's new P3 rows and its P4 row (or finds them stored) and returns the texel's
  // P6 entry.
  P6Entry adopt_p4(const P4Proposal& proposal);

  // The pieces of encode_frozen() for the batched search (pipeline/encode/frozen_search.h):
  // the texel as the comparison sees it, with its candidates;
  FrozenQuery frozen_query(const float* texel) const;
  // the same into `into`, reusing its buffers (a batch refills the same queries tile after tile:
  // fresh half-megabyte buffers per texel cost more in page faults than the copies themselves);
  void frozen_query(const float* texel, FrozenQuery& into) const;
  // the exact search among `order` that only accepts scores >= floor (throws InputError if none
  // does): equal to encode_frozen() whenever the best candidate's score is >= floor and in `order`;
  P6Entry encode_frozen_among(const FrozenQuery& query, const std::vector<uint32_t>& order, double floor) const;
  P6Entry encode_frozen_among(const float* texel, const std::vector<uint32_t>& order, double floor) const;
  // the M planes of a P4 entry (n_phi_v x n_theta_v, phi_v-major): P2 and I2 entries and the
  // product of the P4 and P3 scales;
  void p4_planes(uint32_t p4, std::vector<uint32_t>& p2, std::vector<uint32_t>& i2, std::vector<float>& factor) const;
  // and the cached P2 (luminance) and I2 (chroma) planes with their window statistics.
  const SliceStore& luminance_planes() const { return p2_store_; }
  const SliceStore& chroma_planes() const { return i2_store_; }

  // Dissimilarity of the texel and its reconstruction from (p4, scale), per the similarity settings.
  double texel_dissimilarity(const float* texel, uint32_t p4, float scale) const;

  struct Ctx;  // per-call scratch (public so that helpers in encoder.cpp can name it)

 private:
  struct PlaneRef {
    uint32_t p2, i2;
    float factor;
  };
  struct Query;
  Query frozen_texel_query(const FrozenQuery& f, Ctx& ctx) const;
  struct Match {
    int64_t index = -1;
    double score = -1e300;
    float scale = 1.0f;
  };

  void sync();
  void cache_p1(uint32_t e);
  void cache_i1(uint32_t e);
  void cache_p2(uint32_t e);
  void cache_i2(uint32_t e);
  void cache_m(uint32_t e);
  void cache_p3(uint32_t e);
  void cache_p4(uint32_t e);
  // The planes of a P3 row of M entries m with scales `scale` (n_theta_v each) times factor, appended to out.
  void m_planes(const uint32_t* m, const float* scale, float factor, std::vector<PlaneRef>& out) const;
  // The planes of P3 entry p3 times factor, appended to out (what a P4 entry's group decodes to).
  void p3_planes(uint32_t p3, float factor, std::vector<PlaneRef>& out) const;
  // propose_p4's new P3 entry for group query q: the best frozen M entry per theta_v slice, at the
  // normalized brightness (m and scale: n_theta_v each); its brightness, or a negative value if M is empty.
  double compose_frozen_p3(const Query& q, Ctx& ctx, uint32_t* m, float* scale) const;
  // A P4 row by content: the stored one if it exists, else appended (cached, counted).
  uint32_t store_p4(const uint32_t* p3, const float* scale);

  double bound_for(double threshold, size_t values) const;
  float normalization(double bright) const;
  void planes_of_p4(uint32_t e, std::vector<PlaneRef>& out) const;
  void planes_of_p3(uint32_t e, std::vector<PlaneRef>& out) const;

  // Scores a composite candidate (list of M planes) against the query with its best scale.
  // fixed_scale: the composition at *scale as given (its own scale), else at its least-squares best.
  bool evaluate_composite(const Query& q, const PlaneRef* planes, int np, double bound, Ctx& ctx, double* score,
                          float* scale, bool fixed_scale = false) const;
  Match search_composite(const Query& q, int level, double bound, Ctx& ctx) const;
  // search_composite in two steps: the candidate order (into ctx.order), then the search.
  void order_composite(const Query& q, int level, Ctx& ctx) const;
  void proxy_signature(const Query& q, int level, std::vector<float>& out) const;
  const SignatureTable& signatures(int level) const;
  size_t proxy_k(int level) const;
  // The candidate orders of the `parts` sub-queries (of part_planes planes each) of q that a
  // composition will search at `level`, found in one pass over the level's signatures.
  void prime_orders(const Query& q, int level, int parts, int part_planes, Ctx& ctx) const;
  Match search_composite_in(const Query& q, int level, const std::vector<uint32_t>& order, double bound,
                            Ctx& ctx) const {
    return search_composite_in(q, level, order, bound, ctx, threads_);
  }
  Match search_composite_in(const Query& q, int level, const std::vector<uint32_t>& order, double bound, Ctx& ctx,
                            size_t threads) const;
  // A composition's first search of each part, made before any part inserts (speculate), and what
  // the search finds once the parts before it have (confirm): equal to search_composite then.
  struct Speculation {
    size_t end = 0;  // entries of the level when it ran
    std::vector<uint32_t> order;
    Match best;
  };
  std::vector<Speculation> speculate(const std::vector<Query>& parts, int level, double threshold, Ctx& ctx) const;
  Match confirm(const Query& q, int level, double bound, const Speculation& s, Ctx& ctx) const;
  void check_frozen() const;
  // `stats`: a buffer to hold the window statistics (its capacity is reused).
  Query texel_query(const std::vector<float>& texel, Ctx& ctx, std::vector<float> stats = {}) const;
  P6Entry frozen_entry(const Query& q, const Match& best) const;
  void order_by_rows(const float* qsig, const RowLanes& rows, Ctx& ctx) const;
  Match search_p2(const Query& q, double bound, Ctx& ctx) const;
  Match search_i2(const Query& q, double bound, Ctx& ctx) const;
  Match search_p1(const float* row, float unit, double bound, Ctx& ctx) const;
  Match search_i1(const float* row, float unit, double bound, Ctx& ctx) const;

  // cap: the threshold a repair imposes (the parent's); kNoCap (infinity) leaves the level's own.
  Match encode_p4(const float* texel, Ctx& ctx);
  // spec: the part's speculative first search (compose), or null to search here.
  Match encode_p3(const Query& q, Ctx& ctx, double cap, const Speculation* spec);
  Match encode_m(const Query& q, Ctx& ctx, double cap, const Speculation* spec);
  uint32_t encode_p2(const Query& q, Ctx& ctx, double cap);
  uint32_t encode_i2(const Query& q, Ctx& ctx, double cap);
  static double threshold(double level, double cap);
  struct Composite {
    std::vector<uint32_t> index;
    std::vector<float> scale;  // of each part, divided by norm
    std::vector<PlaneRef> planes;
    float norm = 1;  // the composition's own scale (its brightness over the fixed one)
    double score = 0;
  };
  // parts: the sub-queries (of part_planes planes), searched at `level` with `part_threshold` first.
  template <class EncodePart, class PlanesOf>
  Composite compose(const Query& q, const std::vector<Query>& parts, int part_planes, int level, double part_threshold,
                    const std::vector<float>& bright, double bound, double repair_cap, Ctx& ctx,
                    EncodePart encode_part, PlanesOf planes_of);
  double composition_score(const Query& q, const std::vector<PlaneRef>& planes, float s, Ctx& ctx) const;
  bool failing_parts(const Query& q, const PlaneRef* planes, int np, int part_planes, float s, double bound, Ctx& ctx,
                     std::vector<double>& bad) const;
  static int worst_part(const std::vector<double>& bad, const std::vector<uint8_t>& capped);
  template <class Reuse, class MakeExact>
  void repair_parts(const WindowGeometry& g, bool by_column, const ChannelView* x, int first, int nc, float unit,
                    float* y, std::vector<uint8_t>& exact, double bound, Ctx& ctx, Reuse reuse, MakeExact make_exact);
  // The raw least-squares scale of P1 row e for the absolute row x (the P2 scale of a density).
  float p1_scale(const float* x, uint32_t e) const;
  // A P1 row of the row's shape (its density) with the row's sum as its scale: found stored or appended.
  Match store_p1(const float* row, bool exact);
  // An I1 row of C entries for `row` (a, then b), repaired to the I1 threshold unless exact.
  uint32_t compose_i1(const float* row, float unit, Ctx& ctx, bool exact);
  // The rows [0, n) of a plane, each searched by search(row, ctx) -> Match and then handed in row
  // order to commit(row, match), which inserts on a miss. On several threads the searches run ahead
  // in windows against the code-book as it is; once a commit has grown it (size() moved) the rows
  // after that one are searched again: the same matches as searching each row at its turn.
  template <class Size, class Search, class Commit>
  void rows_ahead(int n, Ctx& ctx, Size size, Search search, Commit commit);
  uint32_t encode_c(float a, float b, float unit, bool exact);

  // Rows by content (hash -> ids), so that no row is stored twice.
  struct ContentIndex {
    std::unordered_map<uint64_t, std::vector<uint32_t>> ids;
  };
  enum Cause { kMiss = 0, kRetry = 1, kExact = 2 };
  Cause cause_ = kMiss;  // of the insertions below the attempt being encoded
  // A row by content: the stored one if it exists, else appended, cached and counted (by cause_,
  // or as exact).
  template <class A, class B>
  uint32_t insert_row(CodebookId id, ContentIndex& index, Table<A>& ta, const A* a, Table<B>* tb, const B* b,
                      bool exact);
  void cache(CodebookId id, uint32_t e);  // the search structures of a new row of `id`
  void count_insert(CodebookId id, bool exact);

  Codebooks& books_;
  Dynamic dyn_;
  Thresholds thresholds_;
  SimilaritySettings settings_;
  AngularGrid grid_;
  WindowGeometry g2_, g1_;
  SliceStore p1_store_, i1_store_, p2_store_, i2_store_;
  // Candidate order of the 1D code-books: P1 by the angle of the row shapes (unit vectors), I1 by
  // the Euclidean distance of the stored (a, b) rows.
  ProxyIndex p1_index_, i1_index_;
  bool indexed_1d() const { return settings_.pruning && settings_.candidate_limit > 0; }
  SignatureTable m_sig_, p3_sig_, p4_sig_;  // proxy signatures (offset-removed means)
  int bands_ = 1;                 // P3 signatures: luminance means per plane over this many alpha bands
  // M signatures: beyond the row means, the luminance over this many beta bands (0 with one band).
  int m_bands() const { return bands_ > 1 ? std::min(bands_, grid_.n_beta) : 0; }
  std::vector<float> p3_mean_;    // per P3 entry and plane, the channel means P4 signatures are made of
  RowLanes p2_lanes_, i2_lanes_;  // row means (offset removed) of the P2 and I2 planes, for their candidate orders
  std::vector<float> m_bright_, p3_bright_, p4_bright_;  // mean of (Y - offset)
  std::unordered_map<uint64_t, uint32_t> m_lookup_;    // (P2, I2) -> M
  ContentIndex p1_rows_, c_rows_, i1_rows_, i2_rows_, p2_rows_, p3_rows_, p4_rows_;
  // C entries bucketed on a square grid of their stored (a, b) values: a C search only visits the
  // cells within its acceptance radius (exactly the linear scan's choice; used when pruning is on).
  std::unordered_map<uint64_t, std::vector<uint32_t>> c_grid_;
  size_t c_indexed_ = 0;
  void index_c(uint32_t e);
  // LAESA pivot index over P4 for the MSE metric (paper 5.1.1): angles between offset-removed
  // entries are a metric, and the least-squares residual is |x'|^2 sin^2(angle).
  static constexpr int kPivots = 8;
  std::vector<uint32_t> pivots_;
  std::vector<double> pivot_angle_;  // P4 entries x kPivots (NaN: undefined)
  std::vector<double> p4_norm_;      // |entry'| over the channels an RGB scale acts on
  double plane_dot(const PlaneRef& a, const PlaneRef& b) const;
  void laesa_insert(uint32_t e);
  mutable EncoderStats stats_;
  size_t threads_ = 1;
};

// Exact node values of a P4 entry at `scale` (3 x grid.samples() floats, coding space, layout
// [channel][AngularGrid::index]) per the decode semantics (no interpolation at nodes; the decoder's
// clamp of RGB at 0 is not applied).
void reconstruct_texel(const Codebooks& books, Dynamic dyn, uint32_t p4, float scale, float* out);

// Dissimilarity of two texels (3 x grid.samples(), coding space) over all planes and channels, with
// no scale fitting: an independent check of what the encoder guarantees.
double texel_dissimilarity(const SimilaritySettings& s, Dynamic dyn, const AngularGrid& grid, const float* texel,
                           const float* reconstruction);

}  // namespace btfvq
