#pragma once
// Which code-book entries to compare first (paper Sec. 4.4: "the search is the bottleneck").
//
// The exact comparison of a slice with a code-vector is an SSIM percentile; it is not a metric, so
// it cannot be indexed directly. The 1D code-books (P1: shapes of beta rows, I1: chroma rows) grow to
// tens of thousands of entries, and a linear scan of them dominates phases 1 and 2. This index keeps
// a cheap Euclidean proxy of every entry in an inverted file: entries are grouped around "leaders"
// (a new vector farther than `radius` from every leader becomes one, the others join their nearest
// leader's list), and a query scans only the lists of its nearest leaders. When the leaders become
// too many for the entries (the radius was too small for the data), the radius doubles and the
// lists are rebuilt: growth stays amortized linear. Everything is deterministic.
#include <cstddef>
#include <cstdint>
#include <vector>

#include "pipeline/util/bounded_heap.h"

namespace btfvq {

// |q - y|^2 over n values, each squared difference and the sum in double, in value order.
float plain_distance(const float* q, const float* y, int n);

// Vectors of `dim` floats kept for linear scans in value-major blocks of kLanes (value i of entry e
// at block e / kLanes, slot i * kLanes + e % kLanes; unused slots 0), so that one pass computes
// kLanes squared distances at once. Each distance is still summed in value order, in Sum: the same
// number as one vector at a time (this file is built without contraction into FMA). Sum = double
// gives plain_distance's numbers (the P2 and I2 candidate orders scan every entry's row means, up
// to 130k entries at 256 x 256); the proxy index sums in float.
template <class Sum>
class Lanes {
 public:
  static constexpr size_t kLanes = 8;
  explicit Lanes(int dim = 0) : dim_(dim) {}
  void append(const float* x);
  size_t size() const { return n_; }
  // Entry e's dim values, as appended, into out.
  void row(size_t e, float* out) const;
  size_t blocks() const { return (n_ + kLanes - 1) / kLanes; }
  // out[e] = |q - entry e|^2 for every entry; out holds blocks() x kLanes.
  void distances(const float* q, float* out) const { distances(q, out, 0, blocks()); }
  // The same for the entries of blocks [first, last) only (out[e] for e in [first, last) x kLanes).
  void distances(const float* q, float* out, size_t first, size_t last) const;
  // The k nearest entries to q (all if fewer), nearest first, ties to the lower index. On up to
  // `threads` threads when there are entries enough: each keeps the k nearest of a run of entries,
  // and the k smallest of those are the k nearest of all ((distance, index) is a total order), so
  // the result does not depend on the threads.
  void nearest(const float* q, size_t k, size_t threads, std::vector<Ranked>& out) const;

 private:
  int dim_ = 0;
  size_t n_ = 0;
  std::vector<float> v_;
};
extern template class Lanes<float>;
extern template class Lanes<double>;
using RowLanes = Lanes<double>;

class ProxyIndex {
 public:
  ProxyIndex() = default;
  ProxyIndex(int dim, float radius);

  int dim() const { return dim_; }
  uint32_t size() const { return uint32_t(vectors_.size() / size_t(dim_ > 0 ? dim_ : 1)); }
  size_t leaders() const { return leaders_.size(); }

  // Adds a vector; its id is the previous size().
  void insert(const float* v);
  // Leaders beyond this many for n entries mean the radius is too small for the data: each list
  // then holds about one entry and a query degenerates into a scan of the leaders (the rule of
  // SignatureTable's direction groups too).
  static size_t leader_budget(size_t n);
  // Up to k ids, nearest first (ties to the lower id), among every member of the lists of the
  // `probes` leaders nearest to q. Approximate only in that an entry nearer than those leaders'
  // members but in another list is not seen.
  void nearest(const float* q, int k, int probes, std::vector<uint32_t>& out) const;

 private:
  static constexpr size_t kLanes = Lanes<float>::kLanes;
  void assign(uint32_t id);
  void rebuild();

  int dim_ = 0;
  float radius_ = 0;
  std::vector<float> vectors_;                // size() x dim
  std::vector<uint32_t> leaders_;             // ids of the leaders
  Lanes<float> leader_lanes_;                 // their vectors
  std::vector<std::vector<uint32_t>> lists_;  // per leader: ids of its members (itself first)
  std::vector<Lanes<float>> list_lanes_;      // per leader: its members' vectors
  std::vector<double> spread_;                // per leader: its farthest member's distance from it
};

}  // namespace btfvq
