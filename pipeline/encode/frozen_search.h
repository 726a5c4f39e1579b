#pragma once
// Phase 3 of the schedule (paper Sec. 5.1, 4.4): the best existing P4 entry for every remaining
// texel, with the code-books frozen. Most of a compression's time is spent here.
//
// Two ways to the same answer:
//  - Pruned: per texel, Encoder::encode_frozen(): candidates in proxy order, each abandoned as soon
//    as more than 2% of its SSIM values fall below the best score so far. Little work per texel,
//    but branchy and sequential: the CPU path when no OpenCL device exists.
//  - Batched: a batch of texels searched at once by kernels/search.cl (or its C++ reference), one
//    texel per work-item with the same abandonment, every SSIM value of a row one vector expression;
//    each completed candidate's score is bracketed by a histogram bin, and the host then settles
//    exactly the few candidates whose brackets reach the best one. Same chosen entries and scales as
//    Pruned (the brackets are conservative and the settling is Pruned's own search).
//  - BatchedMSE (schedule.assign_metric "mse", LDR): no kernel is needed. With the least-squares
//    scale s = <x, y> / <y, y> (offsets removed, plane factors in y) a candidate's squared error is
//    <x, x> - 2 s <x, y> + s^2 <y, y>, and the batch already computes every <x, y> (the scale
//    numerators, grouped by entry) and holds every <y, y>: the error of all candidates is closed
//    form, bracketed by a rounding margin, and the host settles the few whose brackets reach the
//    best one with Pruned's exact search. HDR (chroma not scaled) keeps Pruned.
#include <cstddef>
#include <memory>
#include <vector>

#include "pipeline/encode/encoder.h"

namespace btfvq {

// Stored by number in checkpoints: append only.
enum class SearchPath { Pruned, BatchedOpenCL, BatchedReference, BatchedMSE };

// What the batched path measured (for reports and benchmarks).
struct SearchStats {
  size_t texels = 0;
  size_t scored = 0;    // (texel, candidate) pairs the batch started (most are abandoned early)
  size_t settled = 0;   // candidates then compared exactly on the host
  double batch_seconds = 0, settle_seconds = 0;
  double device_seconds = 0;  // of batch_seconds: scoring alone (the kernel or its reference)
};

class FrozenSearch {
 public:
  // `encoder` must outlive the search and its code-books must not grow meanwhile (phase 3), but
  // for P4 entries taken in by sync().
  // BatchedOpenCL throws DeviceError unless OpenCL is in use and kernel_fits() the grid. Under the
  // MSE metric every batched path is BatchedMSE (HDR: Pruned), and BatchedMSE under SSIM is an
  // InputError.
  FrozenSearch(const Encoder& encoder, SearchPath path, int threads);
  ~FrozenSearch();
  FrozenSearch(const FrozenSearch&) = delete;
  FrozenSearch& operator=(const FrozenSearch&) = delete;

  // The fastest path measured on this kind of machine for this grid (see frozen_search.cpp).
  static SearchPath preferred(const AngularGrid& grid, const SimilaritySettings& settings);
  // Whether kernels/search.cl's padded rows hold planes of this grid at this window radius.
  static bool kernel_fits(const AngularGrid& grid, int radius);

  SearchPath path() const { return path_; }
  const SearchStats& stats() const { return stats_; }

  // Takes in the P4 entries the encoder appended since (phase-3 compositions); the lower
  // code-books must not have changed.
  void sync();

  // Encodes n texels (3 x grid.samples() coding-space floats each, contiguous) into out[0..n).
  void encode(const float* texels, size_t n, P6Entry* out);

  // Under MSE (BatchedMSE): every (texel, candidate) pair's squared error from the closed form and
  // the margin that bounds its rounding: the exact error lies in [error - margin, error + margin].
  void squared_errors(const std::vector<FrozenQuery>& queries, const std::vector<uint32_t>& candidates, size_t slots,
                      std::vector<double>* error, std::vector<double>* margin) const;

  // What the batch computes for every (texel, candidate) pair, candidates of a texel in the given
  // order (for tests): bins[t * slots + k] for candidates[t * slots + k] is the histogram bin of its
  // score, or -1 if it was abandoned (its score fell below a previous candidate's lower bound).
  std::vector<int> bins(const std::vector<FrozenQuery>& queries, const std::vector<uint32_t>& candidates,
                        size_t slots);

  // The score interval [lower, upper] that bin b certifies (with a margin for rounding).
  static void bracket(int bin, double* lower, double* upper);

 private:
  struct Device;
  void encode_pruned(const float* texels, size_t n, P6Entry* out);
  void encode_batched(const float* texels, size_t n, P6Entry* out);
  void encode_batched_mse(const float* texels, size_t n, P6Entry* out);
  // The frozen queries of n texels into queries_, and their candidates (slots per texel).
  std::vector<uint32_t> gather(const float* texels, size_t n, size_t* slots);
  void check_batch(const std::vector<FrozenQuery>& queries, const std::vector<uint32_t>& candidates, size_t slots) const;
  std::vector<float> scale_numerators(const std::vector<FrozenQuery>& queries, const std::vector<uint32_t>& candidates,
                                      size_t slots) const;
  void bins_reference(const std::vector<FrozenQuery>& queries, const std::vector<uint32_t>& candidates, size_t slots,
                      const std::vector<float>& nums, std::vector<int>& out) const;
  void bins_opencl(const std::vector<FrozenQuery>& queries, const std::vector<uint32_t>& candidates, size_t slots,
                   const std::vector<float>& nums, std::vector<int>& out) const;
  std::vector<float> query_block(const FrozenQuery& q) const;
  template <class F>
  void parallel(size_t n, F&& f) const;

  const Encoder& encoder_;
  SearchPath path_;
  int threads_;
  int keep_ = 1;
  std::vector<uint32_t> plane_p2_, plane_i2_;
  std::vector<float> plane_f_, inv_count_;
  std::vector<double> lum_yy_, chroma_yy_;  // per P2 / I2 entry and channel: sum of squares about the offset
  std::vector<float> entry_yy_;              // per P4 entry: the least-squares denominator
  size_t entries_ = 0;                       // P4 entries taken in
  std::unique_ptr<Device> device_;
  std::vector<FrozenQuery> queries_;  // encode_batched's, kept so that each batch refills the same buffers
  SearchStats stats_;
};

}  // namespace btfvq
