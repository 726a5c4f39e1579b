#include "bench/baselines/pca.h"

#include <algorithm>
#include <cmath>
#include <random>

namespace btfvq::baselines {

namespace {

Eigen::MatrixXf orthonormal_columns(const Eigen::MatrixXf& y) {
  Eigen::HouseholderQR<Eigen::MatrixXf> qr(y);
  return qr.householderQ() * Eigen::MatrixXf::Identity(y.rows(), y.cols());
}

// Eigenvectors of a symmetric matrix, largest eigenvalue first.
void sorted_eigen(const Eigen::MatrixXd& g, Eigen::MatrixXd& vectors, Eigen::VectorXd& values) {
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(g);
  vectors = es.eigenvectors().rowwise().reverse();
  values = es.eigenvalues().reverse().cwiseMax(0.0);
}

Components exact(const RowMatrix& x, int k) {
  const Eigen::MatrixXf gf = x.transpose() * x;
  Eigen::MatrixXd v;
  Eigen::VectorXd l;
  sorted_eigen(gf.cast<double>(), v, l);
  Components c;
  c.basis = v.leftCols(k).cast<float>();
  c.sigma = l.head(k).cwiseSqrt().cast<float>();
  c.weights = x * c.basis;
  return c;
}

Components randomized(const RowMatrix& x, int k, uint64_t seed) {
  const Eigen::Index l = std::min<Eigen::Index>(k + 10, std::min(x.rows(), x.cols()));
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> normal;
  Eigen::MatrixXf omega(x.cols(), l);
  for (Eigen::Index i = 0; i < omega.size(); ++i) omega.data()[i] = normal(rng);
  Eigen::MatrixXf y = x * omega;
  for (int it = 0; it < 2; ++it) {
    const Eigen::MatrixXf z = orthonormal_columns(x.transpose() * orthonormal_columns(y));
    y = x * z;
  }
  const Eigen::MatrixXf q = orthonormal_columns(y);          // n x l: the range of x
  const Eigen::MatrixXf b = q.transpose() * x;                // l x d
  Eigen::MatrixXd u;
  Eigen::VectorXd s2;
  sorted_eigen((b * b.transpose()).cast<double>(), u, s2);    // b = U S V^T, b b^T = U S^2 U^T
  Components c;
  c.sigma = s2.head(k).cwiseSqrt().cast<float>();
  const Eigen::MatrixXf uk = u.leftCols(k).cast<float>();
  c.basis = b.transpose() * uk;                               // V S
  for (int i = 0; i < k; ++i) c.basis.col(i) /= std::max(c.sigma(i), 1e-20f);
  c.weights = q * uk * c.sigma.asDiagonal();                  // U S
  return c;
}

}  // namespace

Components top_components(const RowMatrix& x, int k, uint64_t seed) {
  k = int(std::min<Eigen::Index>(k, std::min(x.rows(), x.cols())));
  if (x.cols() <= kExactGramLimit) return exact(x, k);
  return randomized(x, k, seed);
}

uint64_t quantize8(Eigen::Ref<Eigen::VectorXf> v) {
  if (v.size() == 0) return kRangeBytes;
  const float lo = v.minCoeff(), hi = v.maxCoeff();
  const float step = (hi - lo) / 255.0f;
  if (step > 0)
    for (Eigen::Index i = 0; i < v.size(); ++i) v(i) = lo + step * std::round((v(i) - lo) / step);
  return uint64_t(v.size()) + kRangeBytes;
}

}  // namespace btfvq::baselines
