#pragma once
// Proxy signatures of the composite code-books (M, P3, P4: offset-removed means per plane and
// channel) and the cheap distance that orders a search's candidates (docs/similarity.md). Every
// search of phases 1-3 and of the refinement scores the query against all entries of a level, so
// the table keeps a copy in blocks of kLanes entries, value-major, that a loop scans kLanes entries
// at a time. Each entry's sums are still taken in value order, so the distances are bitwise those of
// the one-entry formula (scaled_distance) whatever the block layout, the CPU or the thread count.
#include <cstddef>
#include <cstdint>
#include <vector>

namespace btfvq {

// min over s >= 0 of |q - s y|^2 for one entry y of n values: the one-entry reference.
float scaled_distance(const float* q, const float* y, int n);

class SignatureTable {
 public:
  static constexpr size_t kLanes = 8;
  explicit SignatureTable(int width = 0) : width_(size_t(width)) {}
  size_t width() const { return width_; }
  size_t size() const { return n_; }
  void append(const float* sig);
  const float* row(size_t e) const { return rows_.data() + e * width_; }
  // out[e - first] = scaled_distance(q, row(e), width) for e in [first, last).
  void scaled_distances(const float* q, size_t first, size_t last, float* out) const;

 private:
  size_t width_ = 0, n_ = 0;
  std::vector<float> rows_;    // n x width
  std::vector<float> blocks_;  // ceil(n / kLanes) x width x kLanes; unused lanes 0
  std::vector<double> yy_;     // per entry, sum of y^2 in value order
};

}  // namespace btfvq
