#pragma once
// The k smallest of a stream (by T's operator<, a total order), as a max-heap of at most k: what the
// nearest-neighbour scans of the encoder keep. Most offers fail one comparison with the top.
#include <algorithm>
#include <cstddef>
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

}  // namespace btfvq
