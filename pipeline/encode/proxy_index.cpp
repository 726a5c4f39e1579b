#include "pipeline/encode/proxy_index.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <type_traits>
#include <limits>

#include <btfvq/error.h>
#include "pipeline/util/bounded_heap.h"
#include "pipeline/util/parallel.h"

namespace btfvq {

float plain_distance(const float* q, const float* y, int n) {
  double d = 0;
  for (int i = 0; i < n; ++i) d += double(q[i] - y[i]) * (q[i] - y[i]);
  return float(d);
}

template <class Sum>
void Lanes<Sum>::append(const float* x) {
  if (n_ % kLanes == 0) v_.resize(v_.size() + size_t(dim_) * kLanes, 0.0f);
  float* block = v_.data() + (n_ / kLanes) * size_t(dim_) * kLanes;
  for (int i = 0; i < dim_; ++i) block[size_t(i) * kLanes + n_ % kLanes] = x[i];
  ++n_;
}

template <class Sum>
void Lanes<Sum>::row(size_t e, float* out) const {
  const float* block = v_.data() + (e / kLanes) * size_t(dim_) * kLanes;
  for (int i = 0; i < dim_; ++i) out[i] = block[size_t(i) * kLanes + e % kLanes];
}

// kLanes values as one vector (GCC/Clang vector extensions: element-wise, in the same order as the
// scalar loop, so the same numbers on any vector width, SSE2 included).
typedef float FloatLanes __attribute__((vector_size(sizeof(float) * 8)));
typedef double DoubleLanes __attribute__((vector_size(sizeof(double) * 8)));
template <class Sum>
using SumLanes = std::conditional_t<std::is_same_v<Sum, float>, FloatLanes, DoubleLanes>;

template <class Sum>
void Lanes<Sum>::distances(const float* q, float* out, size_t first, size_t last) const {
  static_assert(kLanes == 8);
  for (size_t b = first; b < last; ++b) {
    const float* block = v_.data() + b * size_t(dim_) * kLanes;
    SumLanes<Sum> s = {};
    for (int i = 0; i < dim_; ++i) {
      FloatLanes y;
      std::memcpy(&y, block + size_t(i) * kLanes, sizeof y);
      const FloatLanes diff = q[i] - y;
      SumLanes<Sum> d;
      if constexpr (std::is_same_v<Sum, float>) d = diff;
      else d = __builtin_convertvector(diff, SumLanes<Sum>);
      s += d * d;
    }
    for (size_t j = 0; j < kLanes; ++j) out[b * kLanes + j] = float(s[j]);
  }
}

namespace {
// Entries a scan needs before Lanes::nearest spreads it over threads: below, the hand-over (about
// 10 microseconds) costs more than half the scan (a 4k-entry row-mean scan takes about 25).
constexpr size_t kParallelScan = 4096;
}  // namespace

template <class Sum>
void Lanes<Sum>::nearest(const float* q, size_t k, size_t threads, std::vector<Ranked>& out) const {
  thread_local std::vector<float> d;
  d.resize(blocks() * kLanes);
  float* dist = d.data();
  const ParallelOptions parts = in_parts(blocks(), threads > 1 && n_ >= kParallelScan ? threads : 1);
  std::vector<std::vector<Ranked>> near(parallel_slots(blocks(), parts));
  parallel_for(0, blocks(), [&](size_t first, size_t last, size_t slot) {
    distances(q, dist, first, last);
    for (size_t e = first * kLanes, end = std::min(last * kLanes, n_); e < end; ++e)
      keep_nearest(near[slot], k, dist[e], uint32_t(e));
  }, parts);
  out.clear();
  for (const std::vector<Ranked>& h : near) out.insert(out.end(), h.begin(), h.end());
  std::sort(out.begin(), out.end());
  out.resize(std::min(out.size(), k));
}

template class Lanes<float>;
template class Lanes<double>;

size_t ProxyIndex::leader_budget(size_t n) { return 64 + 2 * size_t(std::sqrt(double(n))); }

ProxyIndex::ProxyIndex(int dim, float radius) : dim_(dim), radius_(radius), leader_lanes_(dim) {
  if (dim <= 0 || !(radius > 0) || !std::isfinite(radius))
    throw InputError("proxy index: dimension and radius must be positive");
}

void ProxyIndex::insert(const float* v) {
  if (dim_ <= 0) throw InputError("proxy index: not initialized");
  vectors_.insert(vectors_.end(), v, v + dim_);
  assign(size() - 1);
  if (leaders_.size() > leader_budget(size())) rebuild();
}

void ProxyIndex::assign(uint32_t id) {
  const float* v = vectors_.data() + size_t(id) * size_t(dim_);
  thread_local std::vector<float> d;
  d.resize((leaders_.size() + kLanes - 1) / kLanes * kLanes);
  leader_lanes_.distances(v, d.data());
  float best = std::numeric_limits<float>::infinity();
  size_t at = 0;
  for (size_t j = 0; j < leaders_.size(); ++j)
    if (d[j] < best) {
      best = d[j];
      at = j;
    }
  if (leaders_.empty() || best > radius_ * radius_) {
    leaders_.push_back(id);
    leader_lanes_.append(v);
    lists_.push_back({id});
    list_lanes_.emplace_back(dim_).append(v);
    spread_.push_back(0);
  } else {
    lists_[at].push_back(id);
    list_lanes_[at].append(v);
    spread_[at] = std::max(spread_[at], std::sqrt(double(best)));
  }
}

void ProxyIndex::rebuild() {
  while (leaders_.size() > leader_budget(size())) {
    radius_ *= 2;
    leaders_.clear();
    leader_lanes_ = Lanes<float>(dim_);
    lists_.clear();
    list_lanes_.clear();
    spread_.clear();
    for (uint32_t id = 0; id < size(); ++id) assign(id);
  }
}

namespace {

// Offers entries ids[i] at distances d[i] (i < n) to the k nearest in heap. Once the heap is full,
// a block of distances is first compared with the k-th at once: most entries of a list are farther.
void offer_all(std::vector<Ranked>& heap, size_t k, const float* d, const uint32_t* ids, size_t n) {
  constexpr size_t kBlock = 16;
  size_t i = 0;
  for (; i < n && heap.size() < k; ++i) keep_nearest(heap, k, d[i], ids[i]);
  for (; i + kBlock <= n; i += kBlock) {
    const float kth = heap.front().d;
    unsigned pass = 0;
    for (size_t j = 0; j < kBlock; ++j) pass |= unsigned(d[i + j] <= kth) << j;
    for (; pass; pass &= pass - 1) {
      const size_t j = i + size_t(__builtin_ctz(pass));
      keep_nearest(heap, k, d[j], ids[j]);
    }
  }
  for (; i < n; ++i) keep_nearest(heap, k, d[i], ids[i]);
}

// Whether every member of a list is farther from q than the k-th: q is at squared distance dl from
// the leader and each member within `spread` of it, so at least sqrt(dl) - spread from q. The float
// distances are within a few 1e-6 (relative) of the exact ones; the margins are 1e-5.
bool list_beyond(float dl, double spread, float kth) {
  const double root = std::sqrt(double(dl));
  const double lower = root - spread - 1e-5 * (root + spread);
  return lower > 0 && lower * lower * (1 - 1e-5) > double(kth);
}

}  // namespace

void ProxyIndex::nearest(const float* q, int k, int probes, std::vector<uint32_t>& out) const {
  out.clear();
  if (k <= 0 || leaders_.empty()) return;
  thread_local std::vector<float> d;
  thread_local std::vector<Ranked> near_leaders, heap;
  d.resize((leaders_.size() + kLanes - 1) / kLanes * kLanes);
  leader_lanes_.distances(q, d.data());
  near_leaders.clear();
  const size_t p = std::min(leaders_.size(), size_t(std::max(1, probes)));
  for (size_t j = 0; j < leaders_.size(); ++j) keep_nearest(near_leaders, p, d[j], uint32_t(j));
  std::sort(near_leaders.begin(), near_leaders.end());  // nearest list first: the heap tightens soonest
  // Every member of the probed lists: a scan budget spent in insertion order never returned the
  // entries past a long list's first few hundred, and their rows were inserted again.
  heap.clear();
  for (const Ranked& leader : near_leaders) {
    if (heap.size() == size_t(k) && list_beyond(leader.d, spread_[leader.e], heap.front().d)) continue;
    const std::vector<uint32_t>& ids = lists_[leader.e];
    d.resize((ids.size() + kLanes - 1) / kLanes * kLanes);
    list_lanes_[leader.e].distances(q, d.data());
    offer_all(heap, size_t(k), d.data(), ids.data(), ids.size());
  }
  std::sort(heap.begin(), heap.end());
  for (const Ranked& r : heap) out.push_back(r.e);
}

}  // namespace btfvq
