#pragma once
// The linear algebra shared by the PCA baselines: the top principal directions of a data matrix
// (exact eigen-decomposition of the Gram matrix when it is small, a randomized range finder with
// power iterations (Halko, Martinsson, Tropp 2011) when it is not) and the 8-bit scalar
// quantization of factors with a per-vector range, as the papers store their eigen-images.
#include <Eigen/Dense>

#include <cstdint>

#include "bench/baselines/baseline.h"

namespace btfvq::baselines {

using RowMatrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// X ~= weights * basis^T with weights = U Sigma (n x k) and basis = V (d x k, orthonormal columns),
// components ordered by decreasing singular value.
struct Components {
  Eigen::MatrixXf weights;
  Eigen::MatrixXf basis;
  Eigen::VectorXf sigma;
};

// Dimensions up to this are decomposed exactly through the d x d Gram matrix (its O(d^3) eigen-solver
// costs seconds at d = 729, times 27 groups; the randomized path costs O(n d k)).
constexpr Eigen::Index kExactGramLimit = 128;

// The top k components of the rows of x (not centred here: the caller decides what the mean is).
// k is clamped to min(n, d). Randomized for d > kExactGramLimit (oversampling 10, 2 power iterations).
Components top_components(const RowMatrix& x, int k, uint64_t seed = 1);

// Replaces v by its 8-bit quantized value: q = round(255 (v - lo) / (hi - lo)) over the vector's own
// range. Returns the bytes stored: one per value plus kRangeBytes.
uint64_t quantize8(Eigen::Ref<Eigen::VectorXf> v);

}  // namespace btfvq::baselines
