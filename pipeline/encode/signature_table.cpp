#include "pipeline/encode/signature_table.h"

#include <algorithm>
#include <cmath>

#include "pipeline/encode/proxy_index.h"
#include "pipeline/util/bounded_heap.h"
#include "pipeline/util/parallel.h"

namespace btfvq {

namespace {

// The distance from the three sums; float x float products are exact in double, so a sum taken in
// value order is the same number however the loop around it is arranged.
double distance_from(double qq, double qy, double yy) {
  const double s = yy > 0 ? std::max(0.0, qy / yy) : 0.0;
  return qq - 2 * s * qy + s * s * yy;
}

double sum_of_squares(const float* v, size_t n) {
  double s = 0;
  for (size_t i = 0; i < n; ++i) s += double(v[i]) * v[i];
  return s;
}

// The chord between the direction of v (1 / |v| = inv) and a unit leader.
double chord(const float* v, double inv, const std::vector<double>& leader) {
  double s = 0;
  for (size_t i = 0; i < leader.size(); ++i) {
    const double d = double(v[i]) * inv - leader[i];
    s += d * d;
  }
  return std::sqrt(s);
}

// What the rounding of the chords can hide (directions are computed in double).
constexpr double kChordMargin = 1e-7;

// A lower bound of the distance of q (|q|^2 = qq, its direction at chord c from a leader) to any
// entry within chord r of that leader: their chord to q's direction is at least x = c - r, the
// distance |q|^2 sin^2 of the angle, and sin^2 = x^2 (1 - x^2 / 4) up to 90 degrees (x^2 = 2),
// |q|^2 beyond.
double distance_bound(double qq, double c, double r) {
  const double x = c - r - kChordMargin;
  if (x <= 0) return 0;
  const double x2 = x * x;
  return x2 >= 2 ? qq : qq * x2 * (1 - x2 / 4);
}

// True when no entry whose distance is at least `bound` can enter a full heap: the float distances
// round the double ones (relative 2^-24) and these lose up to a few ulp of qq to cancellation.
bool beyond(double bound, double qq, float kth) { return bound * (1 - 1e-6) - 1e-12 * qq > double(kth); }

// qy[a][j] = q . entry j of block a, for A blocks from `base`. Each lane's sum is one chain of
// dependent additions in value order (which fixes its value); the chains of A blocks interleave to
// keep the FMA units busy.
template <size_t A>
void products(const float* q, size_t width, const float* base, double (*qy)[SignatureTable::kLanes]) {
  constexpr size_t kLanes = SignatureTable::kLanes;
  double acc[A][kLanes] = {};
  for (size_t i = 0; i < width; ++i) {
    const double qi = q[i];
    for (size_t a = 0; a < A; ++a) {
      const float* y = base + (a * width + i) * kLanes;
      for (size_t j = 0; j < kLanes; ++j) acc[a][j] += qi * double(y[j]);
    }
  }
  for (size_t a = 0; a < A; ++a) std::copy(acc[a], acc[a] + kLanes, qy[a]);
}

}  // namespace

float scaled_distance(const float* q, const float* y, int n) {
  double qy = 0;
  for (int i = 0; i < n; ++i) qy += double(q[i]) * y[i];
  return float(distance_from(sum_of_squares(q, size_t(n)), qy, sum_of_squares(y, size_t(n))));
}

void SignatureTable::Blocks::append(const float* sig, size_t width, double sq, uint32_t id) {
  const size_t n = ids.size();
  if (n % kLanes == 0) v.resize(v.size() + width * kLanes, 0.0f);
  float* block = v.data() + (n / kLanes) * width * kLanes;
  for (size_t i = 0; i < width; ++i) block[i * kLanes + n % kLanes] = sig[i];
  yy.push_back(sq);
  ids.push_back(id);
}

void SignatureTable::Blocks::select(const float* q, size_t width, double qq, size_t k, size_t first,
                                   std::vector<Neighbour>& heap) const {
  const size_t n = ids.size();
  const size_t blocks = (n + kLanes - 1) / kLanes;
  constexpr size_t kAhead = 4;  // blocks whose products are summed together
  double qy[kAhead][kLanes];
  for (size_t b0 = 0; b0 < blocks; b0 += kAhead) {
    const size_t ahead = std::min(kAhead, blocks - b0);
    const float* base = v.data() + b0 * width * kLanes;
    switch (ahead) {
      case 4: products<4>(q, width, base, qy); break;
      case 3: products<3>(q, width, base, qy); break;
      case 2: products<2>(q, width, base, qy); break;
      default: products<1>(q, width, base, qy); break;
    }
    for (size_t a = 0; a < ahead; ++a) offer(b0 + a, qy[a], qq, k, first, heap);
  }
}

void SignatureTable::Blocks::offer(size_t b, const double* qy, double qq, size_t k, size_t first,
                                  std::vector<Neighbour>& heap) const {
  // Once k are kept, an entry can only enter with a distance up to the k-th (equal: with a lower
  // index, and the groups do not come in index order), qq - qy^2 / yy <= t; below t < float(qq)
  // that needs qy > 0 (else the distance is exactly float(qq)). A test without the division, with
  // a margin far above the rounding of the float distances, so it passes every entry that can
  // enter; those then get the exact distance.
  const size_t lanes = std::min(kLanes, ids.size() - b * kLanes);
  unsigned pass = (1u << lanes) - 1;
  if (heap.size() == k && heap.front().d < float(qq)) {
    const double t = heap.front().d;
    const double limit = qq - t - (1e-6 * std::abs(t) + 1e-12 * qq);
    pass = 0;
    for (size_t j = 0; j < lanes; ++j)
      pass |= unsigned(qy[j] > 0 && qy[j] * qy[j] > limit * yy[b * kLanes + j]) << j;
  }
  for (; pass; pass &= pass - 1) {
    const size_t j = size_t(__builtin_ctz(pass));
    const size_t e = b * kLanes + j;
    if (ids[e] < first) continue;
    keep_smallest(heap, k, Neighbour{float(distance_from(qq, qy[j], yy[e])), ids[e]});
  }
}

void SignatureTable::append(const float* sig) {
  values_.insert(values_.end(), sig, sig + width());
  yy_.push_back(sum_of_squares(sig, width()));
  assign(uint32_t(size() - 1));
  if (groups_.size() > ProxyIndex::leader_budget(size())) rebuild();
}

void SignatureTable::assign(uint32_t e) {
  const float* v = row(e);
  if (!(yy_[e] > 0)) return zero_.append(v, width(), yy_[e], e);
  const double inv = 1 / std::sqrt(yy_[e]);
  double best = 0;
  Group* near = nullptr;
  for (Group& g : groups_)
    if (const double c = chord(v, inv, g.leader); !near || c < best) best = c, near = &g;
  if (!near || best > radius_) {
    near = &groups_.emplace_back();
    for (size_t i = 0; i < width(); ++i) near->leader.push_back(double(v[i]) * inv);
    best = 0;  // the leader is this entry's own direction
  }
  near->radius = std::max(near->radius, best);
  near->members.append(v, width(), yy_[e], e);
}

void SignatureTable::rebuild() {
  while (groups_.size() > ProxyIndex::leader_budget(size())) {
    radius_ *= 2;
    groups_.clear();
    zero_ = {};
    for (uint32_t e = 0; e < size(); ++e) assign(e);
  }
}

void SignatureTable::scaled_distances(const float* q, size_t first, size_t last, float* out) const {
  last = std::min(last, size());
  const double qq = sum_of_squares(q, width());
  for (size_t e = first; e < last; ++e) {
    const float* y = row(e);
    double qy = 0;
    for (size_t i = 0; i < width(); ++i) qy += double(q[i]) * y[i];
    out[e - first] = float(distance_from(qq, qy, yy_[e]));
  }
}

void SignatureTable::nearest_one(const float* q, size_t k, size_t first, std::vector<Neighbour>& out) const {
  out.clear();
  const double qq = sum_of_squares(q, width());
  // The groups by the bound of their members' distances (the entries of norm 0 last but one: at
  // exactly |q|^2); a query of norm 0 is at distance 0 from everything.
  thread_local std::vector<std::pair<double, size_t>> order;
  order.clear();
  const double inv = qq > 0 ? 1 / std::sqrt(qq) : 0;
  for (size_t g = 0; g < groups_.size(); ++g)
    order.emplace_back(qq > 0 ? distance_bound(qq, chord(q, inv, groups_[g].leader), groups_[g].radius) : 0, g);
  order.emplace_back(qq, groups_.size());
  std::sort(order.begin(), order.end());
  for (const auto& [bound, g] : order) {
    if (out.size() == k && beyond(bound, qq, out.front().d)) break;
    (g < groups_.size() ? groups_[g].members : zero_).select(q, width(), qq, k, first, out);
  }
  std::sort(out.begin(), out.end());
}

void SignatureTable::nearest_many(const float* const* qs, size_t nq, size_t k, size_t first, std::vector<Neighbour>* out,
                                  size_t threads) const {
  for (size_t q = 0; q < nq; ++q) out[q].clear();
  if (first >= size() || k == 0) return;
  auto one = [&](size_t q) { nearest_one(qs[q], k, first, out[q]); };
  // Each query is answered alone (the result does not depend on the split); several at once on
  // the threads when the level is large enough to pay for them.
  if (threads != 1 && nq > 1 && (size() - first) * width() * nq >= 64 * 1024)
    parallel_for(0, nq, one, ParallelOptions{threads, 1});
  else
    for (size_t q = 0; q < nq; ++q) one(q);
}

void SignatureTable::extend(const float* q, size_t k, size_t end, std::vector<Neighbour>& known) const {
  const size_t n = size();
  if (end >= n) return;
  std::vector<float> d(n - end);
  scaled_distances(q, end, n, d.data());
  for (size_t e = end; e < n; ++e) known.push_back({d[e - end], uint32_t(e)});
  std::sort(known.begin(), known.end());
  if (known.size() > k) known.resize(k);
}

void SignatureTable::nearest(const float* q, size_t k, std::vector<uint32_t>& out, size_t threads) const {
  std::vector<Neighbour> near;
  nearest_many(&q, 1, k, 0, &near, threads);
  out.resize(near.size());
  for (size_t i = 0; i < near.size(); ++i) out[i] = near[i].e;
}

}  // namespace btfvq
