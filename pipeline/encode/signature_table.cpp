#include "pipeline/encode/signature_table.h"

#include <algorithm>

namespace btfvq {

namespace {

// The distance from the three sums; float x float products are exact in double, so a sum taken in
// value order is the same number however the loop around it is arranged.
float distance_from(double qq, double qy, double yy) {
  const double s = yy > 0 ? std::max(0.0, qy / yy) : 0.0;
  return float(qq - 2 * s * qy + s * s * yy);
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
  return distance_from(sum_of_squares(q, size_t(n)), qy, sum_of_squares(y, size_t(n)));
}

void SignatureTable::append(const float* sig) {
  rows_.insert(rows_.end(), sig, sig + width_);
  if (n_ % kLanes == 0) blocks_.resize(blocks_.size() + width_ * kLanes, 0.0f);
  float* block = blocks_.data() + (n_ / kLanes) * width_ * kLanes;
  for (size_t i = 0; i < width_; ++i) block[i * kLanes + n_ % kLanes] = sig[i];
  yy_.push_back(sum_of_squares(sig, width_));
  ++n_;
}

void SignatureTable::scaled_distances(const float* q, size_t first, size_t last, float* out) const {
  last = std::min(last, n_);
  if (first >= last) return;
  const double qq = sum_of_squares(q, width_);
  for (size_t b = first / kLanes; b * kLanes < last; ++b) {
    const float* block = blocks_.data() + b * width_ * kLanes;
    double qy[kLanes] = {};
    for (size_t i = 0; i < width_; ++i) {
      const double qi = q[i];
      const float* y = block + i * kLanes;
      for (size_t j = 0; j < kLanes; ++j) qy[j] += qi * double(y[j]);
    }
    for (size_t j = 0; j < kLanes; ++j) {
      const size_t e = b * kLanes + j;
      if (e >= first && e < last) out[e - first] = distance_from(qq, qy[j], yy_[e]);
    }
  }
}

}  // namespace btfvq
