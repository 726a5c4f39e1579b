#pragma once
// Similarity of two slices of a resampled texel (paper Sec. 4.4), exactly as docs/similarity.md
// defines it:
//
//  - SSIM (eq. 5) per sample and channel over a (2r+1) x (2r+1) window of neighbouring
//    (alpha, beta) samples of the same (theta_v, phi_v) plane, truncated at the plane borders
//    (along beta only for 1D slices), computed in absolute coding-space units after applying the
//    candidate's best scale; C1 = (k1 L)^2, C2 = (k2 L)^2 with L = 255 (LDR, HDR chroma) or the
//    texel's largest luminance (HDR luminance).
//  - The similarity of two slices is the 2nd percentile of those values: with n values and
//    r = floor(0.02 n), the (r+1)-th smallest. Dissimilarity d = 1 - similarity.
//  - MSE alternative (metric "mse"): d = mean squared difference in absolute units.
//
// Window statistics of code-book slices are computed once per entry (SliceStore) because code-books
// only grow; a comparison then costs one product, one box filter and the SSIM formula per value,
// and stops as soon as more than r values fall below the best score found so far.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "pipeline/btf.h"
#include "pipeline/util/config.h"

namespace btfvq {

enum class Metric { SSIM, MSE };

// The metric named by `key` ("ssim" or "mse"; anything else is a ConfigError naming the key).
Metric metric_from(const ParameterDictionary& d, const std::string& key);

// The "similarity" section of configs/pipeline.json, the one source of its values: the members
// carry none (a default-constructed struct is all zero), defaults() reads the shipped file.
struct SimilaritySettings {
  Metric metric = Metric::SSIM;
  double outlier_fraction = 0;  // the percentile: fraction of values allowed below the score
  double k1 = 0, k2 = 0;        // SSIM constants (Wang et al. 2004)
  double chroma_k2 = 0;         // k2 of the chroma channels (tolerance of their small variances)
  int window_radius = 0;        // 1 -> 3 x 3 windows (3 samples along beta for 1D slices)
  bool pruning = false;         // abandon candidates early; false = exhaustive (for tests)
  int proxy_candidates = 0;     // candidates tried first, in order of a cheap proxy distance
  int candidate_limit = 0;      // > 0: evaluate only this many best-by-proxy candidates (approximate)
  int proxy_bands = 0;          // P3 / M proxies: luminance means over this many alpha / beta bands

  // Reads the "similarity" section; unknown keys are reported by the dictionary's check_unused().
  static SimilaritySettings from(const ParameterDictionary& d);
  static SimilaritySettings defaults();  // from(the shipped configs/pipeline.json)
};

// Offset about which an RGB scale acts on a coding-space channel (RGB = A (Y-16, Cb-128, Cr-128)).
inline float channel_offset(Dynamic dyn, int channel) {
  if (dyn == Dynamic::HDR) return 0.0f;
  return channel == 0 ? 16.0f : 128.0f;
}
// Whether scaling RGB scales this channel (LDR: all three about their offsets; HDR: luminance only).
inline bool channel_scales(Dynamic dyn, int channel) { return dyn == Dynamic::LDR || channel == 0; }

// Sample layout of one plane (rows x cols, row-major) and its truncated windows.
class WindowGeometry {
 public:
  WindowGeometry() = default;
  WindowGeometry(int rows, int cols, int radius);
  int rows() const { return rows_; }
  int cols() const { return cols_; }
  int size() const { return rows_ * cols_; }
  int radius() const { return radius_; }
  // 1 / (number of samples in the window around sample i).
  float inv_count(int i) const { return inv_count_[size_t(i)]; }
  // Window sums of v (truncated box filter), written to out.
  void box(const float* v, float* out, float* tmp) const;
  // Window mean and variance of v.
  void stats(const float* v, float* mean, float* var) const;

 private:
  int rows_ = 0, cols_ = 0, radius_ = 1;
  std::vector<float> inv_count_;
};

// One channel of one plane with its window statistics (raw coding-space values).
struct ChannelView {
  const float* v = nullptr;
  const float* mean = nullptr;
  const float* var = nullptr;
  double sum = 0;    // sum of v
  double sumsq = 0;  // sum of v^2
  double row_sum(int r, int cols) const {
    double s = 0;
    for (int c = 0; c < cols; ++c) s += v[r * cols + c];
    return s;
  }
};

// Append-only copies of code-book slices (channels x plane) with their window statistics.
class SliceStore {
 public:
  SliceStore() = default;
  SliceStore(int channels, const WindowGeometry* g);
  uint32_t size() const { return uint32_t(sums_.size() / size_t(channels_ * 2)); }
  int channels() const { return channels_; }
  void append(const float* values /* channels x plane size */);
  ChannelView view(uint32_t entry, int channel) const;
  const float* values(uint32_t entry) const { return data_.data() + size_t(entry) * stride_; }
  // Every entry's block, `stride()` floats each: values, window means, window variances, each
  // channels x plane size (for uploading the store to a compute device).
  const std::vector<float>& blocks() const { return data_; }
  size_t stride() const { return stride_; }

 private:
  int channels_ = 0;
  const WindowGeometry* g_ = nullptr;
  size_t stride_ = 0;
  std::vector<float> data_;    // per entry: values, means, variances (each channels x plane)
  std::vector<double> sums_;   // per entry and channel: sum, sum of squares
};

// Per-comparison constants of the three channels.
struct SsimConstants {
  float c1[3] = {0, 0, 0}, c2[3] = {0, 0, 0};
  static SsimConstants make(const SimilaritySettings& s, Dynamic dyn, float luminance_range);
};

// Affine map of raw stored values to absolute units: abs = a + b v.
struct Affine {
  float a = 0, b = 1;
};

// The score of one candidate, accumulated plane by plane: SSIM keeps the values that can still be
// among the r+1 smallest (batched selection) and counts those below the bound; MSE keeps the sum of
// squared differences. Scores are
// "higher is better": SSIM percentile, or minus the sum of squares.
class ScoreAccumulator {
 public:
  void reset(Metric m, size_t total_values, double outlier_fraction, double bound);
  // Adds one plane-channel of values; returns false once the candidate cannot reach the bound.
  bool add_ssim(const float* values, int n);
  bool add_squared_error(double sum);
  double score() const;
  bool alive() const { return alive_; }

 private:
  Metric metric_ = Metric::SSIM;
  size_t keep_ = 1;
  double bound_ = -1e300;
  mutable std::vector<float> buffer_;  // (score() selects in place) candidates for the (r+1)-th smallest value: used_ of them
  size_t used_ = 0;
  float tau_ = 0;     // values >= tau_ cannot be among the r+1 smallest
  size_t below_ = 0;  // values strictly below the bound so far
  double sse_ = 0;
  bool alive_ = true;
};

// The SSIM value of every sample of one plane-channel x (absolute = ax) against y (absolute = ay),
// in scratch (3 x plane size floats); returns the pointer to the g.size() values.
float* ssim_values(const WindowGeometry& g, const ChannelView& x, Affine ax, const ChannelView& y, Affine ay, float c1,
                   float c2, float* scratch);

// Sum over the n values of one plane-channel of (x absolute - y absolute)^2, in double.
double squared_error(int n, const ChannelView& x, Affine ax, const ChannelView& y, Affine ay);

// Compares one plane-channel x (absolute = ax) with y (absolute = ay) and adds it to acc.
// scratch must hold 3 x plane size floats.
bool accumulate_channel(const WindowGeometry& g, Metric metric, const ChannelView& x, Affine ax, const ChannelView& y,
                        Affine ay, float c1, float c2, ScoreAccumulator& acc, float* scratch);

// 1D slices (rows == 1, radius 1) whose score is the minimum (r = 0): the same values as
// accumulate_channel, but stops at the first one below `bound` (returns false). On success *score is
// the minimum.
bool min_ssim_row(const WindowGeometry& g, const ChannelView& x, Affine ax, const ChannelView& y, Affine ay, float c1,
                  float c2, double bound, double* score);

// Converts a score into a dissimilarity d (SSIM: 1 - score; MSE: mean squared error) and back.
double score_to_dissimilarity(Metric m, double score, size_t total_values);
double dissimilarity_to_score(Metric m, double d, size_t total_values);

// Convenience for tests and tools: the similarity (1 - d for SSIM, -MSE for MSE) of two slices
// made of `planes` planes of g, each with `channels` channels starting at `first_channel`
// (layout [channel][plane][sample]), both in absolute units, without any scale.
double slice_similarity(const SimilaritySettings& s, Dynamic dyn, const WindowGeometry& g, const float* x,
                        const float* y, int planes, int first_channel, int channels, float luminance_range);

}  // namespace btfvq
