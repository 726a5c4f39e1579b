#include "pipeline/encode/signature_table.h"

#include <algorithm>
#include <numeric>

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
  if (n % kLanes == 0) v.resize(v.size() + width * kLanes, 0.0f);
  float* block = v.data() + (n / kLanes) * width * kLanes;
  for (size_t i = 0; i < width; ++i) block[i * kLanes + n % kLanes] = sig[i];
  yy.push_back(sum_of_squares(sig, width));
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

void SignatureTable::nearest(const float* q, size_t k, std::vector<uint32_t>& out, size_t threads) const {
  const size_t n = size();
  k = std::min(k, n);
  out.resize(n);
  if (k == 0) {
    out.clear();
    return;
  }
  std::vector<float> d(n);
  // A large level is split over the threads (the growing phases search on one thread otherwise);
  // each entry's distance is the same on any thread.
  const size_t grain = 64 * kLanes;
  if (threads != 1 && n * width() >= 64 * 1024)
    parallel_for(0, (n + grain - 1) / grain, [&](size_t c) {
      rows_.distances(q, c * grain, std::min(n, (c + 1) * grain), d.data() + c * grain);
    }, ParallelOptions{threads, 1});
  else
    rows_.distances(q, 0, n, d.data());
  std::iota(out.begin(), out.end(), 0u);
  auto closer = [&](uint32_t a, uint32_t b) { return d[a] < d[b] || (d[a] == d[b] && a < b); };
  std::nth_element(out.begin(), out.begin() + ptrdiff_t(k - 1), out.end(), closer);
  std::sort(out.begin(), out.begin() + ptrdiff_t(k), closer);
  out.resize(k);
}

}  // namespace btfvq
