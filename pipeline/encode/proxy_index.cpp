#include "pipeline/encode/proxy_index.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <btfvq/error.h>

namespace btfvq {

namespace {

// Leaders beyond this many for n entries mean the radius is too small for the data: each list then
// holds about one entry and a query degenerates into a scan of the leaders.
size_t leader_budget(size_t n) { return 64 + 2 * size_t(std::sqrt(double(n))); }

struct Ranked {
  float d;
  uint32_t id;
  bool operator<(const Ranked& o) const { return d < o.d || (d == o.d && id < o.id); }
};

}  // namespace

ProxyIndex::ProxyIndex(int dim, float radius) : dim_(dim), radius_(radius) {
  if (dim <= 0 || !(radius > 0) || !std::isfinite(radius))
    throw InputError("proxy index: dimension and radius must be positive");
}

float ProxyIndex::distance2(const float* a, const float* b) const {
  float s = 0;
  for (int i = 0; i < dim_; ++i) {
    const float d = a[i] - b[i];
    s += d * d;
  }
  return s;
}

void ProxyIndex::insert(const float* v) {
  if (dim_ <= 0) throw InputError("proxy index: not initialized");
  vectors_.insert(vectors_.end(), v, v + dim_);
  assign(size() - 1);
  if (leaders_.size() > leader_budget(size())) rebuild();
}

void ProxyIndex::assign(uint32_t id) {
  const float* v = vectors_.data() + size_t(id) * size_t(dim_);
  float best = std::numeric_limits<float>::infinity();
  size_t at = 0;
  for (size_t j = 0; j < leaders_.size(); ++j) {
    const float d = distance2(v, vectors_.data() + size_t(leaders_[j]) * size_t(dim_));
    if (d < best) {
      best = d;
      at = j;
    }
  }
  if (leaders_.empty() || best > radius_ * radius_) {
    leaders_.push_back(id);
    lists_.push_back({id});
    list_vectors_.emplace_back(v, v + dim_);
  } else {
    lists_[at].push_back(id);
    list_vectors_[at].insert(list_vectors_[at].end(), v, v + dim_);
  }
}

void ProxyIndex::rebuild() {
  while (leaders_.size() > leader_budget(size())) {
    radius_ *= 2;
    leaders_.clear();
    lists_.clear();
    list_vectors_.clear();
    for (uint32_t id = 0; id < size(); ++id) assign(id);
  }
}

void ProxyIndex::nearest(const float* q, int k, int probes, std::vector<uint32_t>& out) const {
  out.clear();
  if (k <= 0 || leaders_.empty()) return;
  thread_local std::vector<Ranked> ranked;
  ranked.clear();
  for (size_t j = 0; j < leaders_.size(); ++j)
    ranked.push_back({distance2(q, vectors_.data() + size_t(leaders_[j]) * size_t(dim_)), uint32_t(j)});
  const size_t p = std::min(ranked.size(), size_t(std::max(1, probes)));
  std::partial_sort(ranked.begin(), ranked.begin() + std::ptrdiff_t(p), ranked.end());
  thread_local std::vector<Ranked> members;
  members.clear();
  // Every member of the probed lists: a scan budget spent in insertion order never returned the
  // entries past a long list's first few hundred, and their rows were inserted again.
  for (size_t j = 0; j < p; ++j) {
    const std::vector<uint32_t>& ids = lists_[ranked[j].id];
    const float* v = list_vectors_[ranked[j].id].data();
    for (size_t i = 0; i < ids.size(); ++i) members.push_back({distance2(q, v + i * size_t(dim_)), ids[i]});
  }
  const size_t n = std::min(members.size(), size_t(k));
  std::partial_sort(members.begin(), members.begin() + std::ptrdiff_t(n), members.end());
  for (size_t i = 0; i < n; ++i) out.push_back(members[i].id);
}

}  // namespace btfvq
