#pragma once
// Proxy signatures of the composite code-books (M, P3, P4: offset-removed means per plane and
// channel) and the cheap distance that orders a search's candidates (docs/similarity.md). Every
// search of phases 1-3 and of the refinement wants the k entries nearest to its query among all
// entries of a level (an M search at 256 x 256: up to a hundred thousand entries), so the table
// answers without scoring every entry, and exactly: the answer is the k first of all entries by
// (distance, index), bit for bit what scoring each entry with the one-entry formula gives.
//
// The distance min over s >= 0 of |q - s y|^2 is |q|^2 sin^2 of the angle between q and y (|q|^2
// beyond 90 degrees), so the entries are grouped by direction: a new entry joins the nearest
// "leader" direction within `radius` (the chord between unit vectors) or becomes one, and each group
// keeps the largest chord of its members. A query orders the groups by the lower bound of the
// distance that the triangle inequality on chords gives their members, and stops at the first group
// whose bound exceeds the k-th distance found. Entries are in blocks of kLanes, value-major, so a
// group is scored kLanes entries at a time; each entry's sums are still taken in value order, so
// the distances are bitwise those of the one-entry formula whatever the layout, the CPU or the
// thread count. When the groups become too many for the entries the radius doubles and the groups
// are rebuilt (as ProxyIndex does): growth stays amortized linear.
//
// (Tried and dropped: a lower bound from per-bin sums, scoring entries in the order of their bound.
// The bound was loose on P4 signatures and the one-at-a-time exact scores cost more than the block
// scan they saved: leather 128 spent twice the CPU time in the search order.)
#include <cstddef>
#include <cstdint>
#include <vector>
#include "pipeline/util/bounded_heap.h"

namespace btfvq {

// min over s >= 0 of |q - s y|^2 for one entry y of n values: the one-entry reference.
float scaled_distance(const float* q, const float* y, int n);

class SignatureTable {
 public:
  static constexpr size_t kLanes = 8;
  explicit SignatureTable(int width = 0) : width_(size_t(width)) {}
  size_t width() const { return width_; }
  size_t size() const { return yy_.size(); }
  size_t groups() const { return groups_.size(); }
  void append(const float* sig);
  const float* row(size_t e) const { return values_.data() + e * width(); }
  // out[e - first] = scaled_distance(q, row(e), width) for e in [first, last).
  void scaled_distances(const float* q, size_t first, size_t last, float* out) const;
  // The min(k, size()) entries nearest to q, nearest first, ties to the lower index; the result
  // the same for any number of `threads` (ParallelOptions::threads).
  void nearest(const float* q, size_t k, std::vector<uint32_t>& out, size_t threads = 1) const;

  // An entry and its scaled distance to a query; ordered by (distance, index).
  using Neighbour = Ranked;
  // For each of the nq queries, the min(k, size() - first) entries of [first, size()) nearest to
  // it, nearest first (a composition searches its 7 or 16 parts against the same level; the
  // queries are spread over `threads`).
  void nearest_many(const float* const* qs, size_t nq, size_t k, size_t first, std::vector<Neighbour>* out,
                    size_t threads = 1) const;
  // `known` holds the k nearest among the entries below `end`: made the k nearest among all entries
  // by scoring only those appended since (the result nearest() gives, since the order is total).
  void extend(const float* q, size_t k, size_t end, std::vector<Neighbour>& known) const;

 private:
  // A group's entries in blocks of kLanes, value-major, with their ids and sums of squares.
  struct Blocks {
    std::vector<float> v;  // ceil(n / kLanes) x width x kLanes; unused lanes 0
    std::vector<double> yy;
    std::vector<uint32_t> ids;
    void append(const float* sig, size_t width, double yy, uint32_t id);
    // Offers every entry of id >= first to the max-heap of the k nearest (a Neighbour heap).
    void select(const float* q, size_t width, double qq, size_t k, size_t first, std::vector<Neighbour>& heap) const;
    // The same for the entries of block b, given their products qy with the query.
    void offer(size_t b, const double* qy, double qq, size_t k, size_t first, std::vector<Neighbour>& heap) const;
  };
  struct Group {
    std::vector<double> leader;  // unit vector
    double radius = 0;           // largest chord of a member to the leader
    Blocks members;
  };
  void assign(uint32_t e);
  void rebuild();
  void nearest_one(const float* q, size_t k, size_t first, std::vector<Neighbour>& out) const;

  size_t width_ = 0;
  double radius_ = 0.05;         // chord within which an entry joins a leader
  std::vector<float> values_;    // row-major copy
  std::vector<double> yy_;       // per entry
  std::vector<Group> groups_;
  Blocks zero_;                  // entries of norm 0: no direction, distance |q|^2 to every query
};

}  // namespace btfvq
