#include "pipeline/encode/signature_table.h"

#include <algorithm>
#include <cmath>
#include <numeric>

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

}  // namespace

float scaled_distance(const float* q, const float* y, int n) {
  double qy = 0;
  for (int i = 0; i < n; ++i) qy += double(q[i]) * y[i];
  return float(distance_from(sum_of_squares(q, size_t(n)), qy, sum_of_squares(y, size_t(n))));
}

void SignatureTable::Blocks::append(const float* sig) {
  if (n % kLanes == 0) {
    v.resize(v.size() + width * kLanes, 0.0f);
    yy.resize(yy.size() + kLanes, 0.0);
  }
  float* block = v.data() + (n / kLanes) * width * kLanes;
  for (size_t i = 0; i < width; ++i) block[i * kLanes + n % kLanes] = sig[i];
  yy[n] = sum_of_squares(sig, width);
  ++n;
}

void SignatureTable::Blocks::distances(const float* q, size_t first, size_t last, float* out) const {
  last = std::min(last, n);
  if (first >= last) return;
  const double qq = sum_of_squares(q, width);
  for (size_t b = first / kLanes; b * kLanes < last; ++b) {
    const float* block = v.data() + b * width * kLanes;
    double qy[kLanes] = {};
    for (size_t i = 0; i < width; ++i) {
      const double qi = q[i];
      const float* y = block + i * kLanes;
      for (size_t j = 0; j < kLanes; ++j) qy[j] += qi * double(y[j]);
    }
    for (size_t j = 0; j < kLanes; ++j) {
      const size_t e = b * kLanes + j;
      if (e >= first && e < last) out[e - first] = float(distance_from(qq, qy[j], yy[e]));
    }
  }
}

void SignatureTable::append(const float* sig) {
  values_.insert(values_.end(), sig, sig + width());
  rows_.append(sig);
}

void SignatureTable::scaled_distances(const float* q, size_t first, size_t last, float* out) const {
  rows_.distances(q, first, last, out);
}

namespace {

// The sums q . y of one query with the entries of kGroup blocks (values in double, block after block,
// each value-major): each entry's sum in value order, as Blocks::distances() takes it (the same
// bits), the blocks' sums side by side so that the additions do not wait on each other.
constexpr size_t kGroup = 4;
void group_sums(const float* q, size_t width, const double* yd, double* out) {
  constexpr size_t L = SignatureTable::kLanes;
  double acc[kGroup][L] = {};
  for (size_t i = 0; i < width; ++i) {
    const double qi = q[i];
    for (size_t g = 0; g < kGroup; ++g) {
      const double* y = yd + (g * width + i) * L;
      for (size_t j = 0; j < L; ++j) acc[g][j] += qi * y[j];
    }
  }
  for (size_t g = 0; g < kGroup; ++g) std::copy(acc[g], acc[g] + L, out + g * L);
}

}  // namespace

void SignatureTable::Blocks::select(const float* const* qs, const double* qq, size_t nq, size_t k, size_t first,
                                   size_t last, std::vector<Neighbour>* heaps) const {
  last = std::min(last, n);
  if (first >= last || k == 0) return;
  const size_t blocks = v.size() / (width * kLanes);
  std::vector<double> yd(kGroup * width * kLanes), qy(kGroup * kLanes);
  for (size_t b0 = first / kLanes; b0 * kLanes < last; b0 += kGroup) {
    // kGroup blocks in double once (they stay in the cache for all queries); past the table's
    // last block, zeros.
    for (size_t g = 0; g < kGroup; ++g) {
      double* out = yd.data() + g * width * kLanes;
      if (b0 + g < blocks) {
        const float* block = v.data() + (b0 + g) * width * kLanes;
        for (size_t i = 0; i < width * kLanes; ++i) out[i] = block[i];
      } else {
        std::fill(out, out + width * kLanes, 0.0);
      }
    }
    for (size_t q = 0; q < nq; ++q) {
      group_sums(qs[q], width, yd.data(), qy.data());
      std::vector<Neighbour>& heap = heaps[q];
      for (size_t g = 0; g < kGroup && (b0 + g) * kLanes < last; ++g) {
        const size_t b = b0 + g;
        const double* a = qy.data() + g * kLanes;
        const double* yb = yy.data() + b * kLanes;
        // Once k are kept, an entry can only enter with a distance below the k-th, qq - qy^2 / yy < t
        // (qy > 0; else the distance is qq, never below): a test without the division, with a margin
        // far above the rounding of the float distances, so it passes every entry that can enter;
        // those then get the exact distance.
        unsigned pass = (1u << kLanes) - 1;
        if (heap.size() == k && heap.front().d <= qq[q]) {
          const double t = heap.front().d;
          const double limit = qq[q] - t - (1e-6 * std::abs(t) + 1e-12 * qq[q]);
          pass = 0;
          for (size_t j = 0; j < kLanes; ++j) pass |= unsigned(a[j] > 0 && a[j] * a[j] > limit * yb[j]) << j;
        }
        for (; pass; pass &= pass - 1) {
          const size_t e = b * kLanes + size_t(__builtin_ctz(pass));
          if (e < first || e >= last) continue;
          const size_t j = e - b * kLanes;
          keep_smallest(heap, k, Neighbour{float(distance_from(qq[q], a[j], yy[e])), uint32_t(e)});
        }
      }
    }
  }
}

void SignatureTable::nearest_many(const float* const* qs, size_t nq, size_t k, size_t first, std::vector<Neighbour>* out,
                                  size_t threads) const {
  const size_t n = size();
  std::vector<double> qq(nq);
  for (size_t q = 0; q < nq; ++q) {
    qq[q] = sum_of_squares(qs[q], width());
    out[q].clear();
  }
  if (first >= n || k == 0) return;
  // A large level is split over the threads (the growing phases search on one thread otherwise);
  // each part keeps its own k nearest, and the k nearest of their union are the same for any split.
  const size_t grain = 64 * kLanes, from = first / kLanes * kLanes;
  const size_t parts = threads != 1 && (n - first) * width() * nq >= 64 * 1024 ? (n - from + grain - 1) / grain : 1;
  if (parts == 1) {
    rows_.select(qs, qq.data(), nq, k, first, n, out);
  } else {
    std::vector<std::vector<Neighbour>> heaps(parts * nq);
    parallel_for(0, parts, [&](size_t c) {
      rows_.select(qs, qq.data(), nq, k, std::max(first, from + c * grain), std::min(n, from + (c + 1) * grain),
                   heaps.data() + c * nq);
    }, ParallelOptions{threads, 1});
    for (size_t c = 0; c < parts; ++c)
      for (size_t q = 0; q < nq; ++q) out[q].insert(out[q].end(), heaps[c * nq + q].begin(), heaps[c * nq + q].end());
  }
  for (size_t q = 0; q < nq; ++q) {
    std::sort(out[q].begin(), out[q].end());
    if (out[q].size() > k) out[q].resize(k);
  }
}

void SignatureTable::extend(const float* q, size_t k, size_t end, std::vector<Neighbour>& known) const {
  const size_t n = size();
  if (end >= n) return;
  std::vector<float> d(n - end);
  rows_.distances(q, end, n, d.data());
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
