#include "pipeline/decode/albedo.h"

#include <cmath>

#include "pipeline/parametrization.h"

namespace btfvq {

Rgb albedo(const Decoder& decoder, size_t material, int x, int y, const Vec3& view) {
  const AngularGrid& g = decoder.database().codebooks.grid;
  const Direction v = to_direction(view);
  // 3-point Gauss-Legendre nodes and weights on [0, 1].
  constexpr double kNode[3] = {0.5 - 0.3872983346207417, 0.5, 0.5 + 0.3872983346207417};
  constexpr double kWeight[3] = {5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0};
  double r = 0, gr = 0, b = 0;
  if (!(v.theta <= 90.0)) {
    decoder.evaluate(material, x, y, {0, 0}, v);  // still reports a bad material index
    return {};
  }
  for (int ai = 0; ai + 1 < g.n_alpha; ++ai) {
    const double a0 = g.alpha_node(ai), a1 = g.alpha_node(ai + 1);
    for (int bi = 0; bi + 1 < g.n_beta; ++bi) {
      const double b0 = g.beta_node(bi), b1 = g.beta_node(bi + 1);
      const double cell = (a1 - a0) * (b1 - b0) * kDeg * kDeg;
      for (int i = 0; i < 3; ++i) {
        const double alpha = a0 + kNode[i] * (a1 - a0);
        for (int j = 0; j < 3; ++j) {
          const double beta = b0 + kNode[j] * (b1 - b0);
          const Rgb f = decoder.evaluate(material, x, y, from_onion({alpha, beta}, v.phi), v);
          // cos(theta_i) = cos(alpha) cos(beta); the Jacobian of the onion map is cos(beta).
          const double cb = std::cos(beta * kDeg);
          const double w = kWeight[i] * kWeight[j] * cell * std::cos(alpha * kDeg) * cb * cb;
          r += w * f.r;
          gr += w * f.g;
          b += w * f.b;
        }
      }
    }
  }
  return {float(r), float(gr), float(b)};
}

}  // namespace btfvq
