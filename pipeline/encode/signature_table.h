#pragma once
// Proxy signatures of the composite code-books (M, P3, P4: offset-removed means per plane and
// channel) and the cheap distance that orders a search's candidates (docs/similarity.md). Every
// search of phases 1-3 and of the refinement wants the k entries nearest to its query among all
// entries of a level (a P4 search at 256 x 256: some 3,000 entries of 336 values), so the table
// keeps a copy in blocks of kLanes entries, value-major, that a loop scans kLanes entries at a
// time. Each entry's sums are still taken in value order, so the distances are bitwise those of the
// one-entry formula (scaled_distance) whatever the layout, the CPU or the thread count.
//
// (Tried and dropped: a lower bound from per-bin sums, scoring entries in the order of their bound.
// The bound was loose on P4 signatures and the one-at-a-time exact scores cost more than the block
// scan they saved: leather 128 spent twice the CPU time in the search order.)
#include <cstddef>
#include <cstdint>
#include <vector>

namespace btfvq {

// min over s >= 0 of |q - s y|^2 for one entry y of n values: the one-entry reference.
float scaled_distance(const float* q, const float* y, int n);

class SignatureTable {
 public:
  static constexpr size_t kLanes = 8;
  explicit SignatureTable(int width = 0) { rows_.width = size_t(width); }
  size_t width() const { return rows_.width; }
  size_t size() const { return rows_.n; }
  void append(const float* sig);
  const float* row(size_t e) const { return values_.data() + e * width(); }
  // out[e - first] = scaled_distance(q, row(e), width) for e in [first, last).
  void scaled_distances(const float* q, size_t first, size_t last, float* out) const;
  // The min(k, size()) entries nearest to q, nearest first, ties to the lower index; the scan on
  // up to `threads` threads (ParallelOptions::threads), the result the same for any number.
  void nearest(const float* q, size_t k, std::vector<uint32_t>& out, size_t threads = 1) const;

  // An entry and its scaled distance to a query; ordered by (distance, index).
  struct Neighbour {
    float d;
    uint32_t e;
    bool operator<(const Neighbour& o) const { return d < o.d || (d == o.d && e < o.e); }
  };
  // For each of the nq queries, the min(k, size() - first) entries of [first, size()) nearest to
  // it, nearest first: one pass over the table for all of them (a composition searches its 7 or 16
  // parts against the same level, and the scan is bound by reading the table, not by arithmetic).
  void nearest_many(const float* const* qs, size_t nq, size_t k, size_t first, std::vector<Neighbour>* out,
                    size_t threads = 1) const;
  // `known` holds the k nearest among the entries below `end`: made the k nearest among all entries
  // by scoring only those appended since (the result nearest() gives, since the order is total).
  void extend(const float* q, size_t k, size_t end, std::vector<Neighbour>& known) const;

 private:
  struct Blocks {  // n entries of `width` values, kLanes per block, with their sums of squares
    size_t width = 0, n = 0;
    std::vector<float> v;     // ceil(n / kLanes) x width x kLanes; unused lanes 0
    std::vector<double> yy;  // per entry
    void append(const float* sig);
    void distances(const float* q, size_t first, size_t last, float* out) const;
    // The k nearest of [first, last) to each query, unsorted, into heaps[q] (max-heaps by Neighbour).
    void select(const float* const* qs, const double* qq, size_t nq, size_t k, size_t first, size_t last,
                std::vector<Neighbour>* heaps) const;
  };
  std::vector<float> values_;  // row-major copy
  Blocks rows_;
};

}  // namespace btfvq
