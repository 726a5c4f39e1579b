#pragma once
// The k smallest of a stream (by T's operator<, a total order), as a max-heap of at most k: what the
// nearest-neighbour scans of the encoder keep. Most offers fail one comparison with the top.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace btfvq {

template <class T>
void keep_smallest(std::vector<T>& heap, size_t k, const T& c) {
  if (heap.size() < k) {
    heap.push_back(c);
    std::push_heap(heap.begin(), heap.end());
  } else if (k > 0 && c < heap.front()) {
    std::pop_heap(heap.begin(), heap.end());
    heap.back() = c;
    std::push_heap(heap.begin(), heap.end());
  }
}

// An entry and its distance to a query, ordered by (distance, index): a total order, so the k
// nearest are the same whichever order the entries are offered in.
struct Ranked {
  float d;
  uint32_t e;
  bool operator<(const Ranked& o) const { return d < o.d || (d == o.d && e < o.e); }
};

// Offers entry e at distance d to the k nearest kept in heap; the first test alone turns most away.
inline void keep_nearest(std::vector<Ranked>& heap, size_t k, float d, uint32_t e) {
  if (heap.size() == k && d > heap.front().d) return;
  keep_smallest(heap, k, Ranked{d, e});
}

}  // namespace btfvq
