#pragma once
// Albedo of a texel for a view (paper Sec. 5.2, eq. 6): a(x, omega_v) = integral over the hemisphere
// of F_x(omega_i, omega_v) cos(theta_i) d omega_i, of the decoded RGB exactly as Decoder::evaluate
// returns it (gamma-encoded 0..255 codes for LDR, linear radiance for HDR; in those units x sr).
//
// The onion parametrization makes this a tensor-product quadrature: d omega = cos(beta) d alpha
// d beta, and inside one (alpha, beta) cell of the grid the decoded value is linear in alpha and a
// cubic in beta (docs/btfbase-format.md steps 4-5), so a 3 x 3 Gauss-Legendre rule per cell is accurate to far
// better than 1% (tests/test_sampling.cpp checks it against a brute-force integration).
#include <cstddef>

#include "pipeline/decode/decoder.h"
#include <btfvq/directions.h>

namespace btfvq {

// Texel (x, y) wrapped modulo the material size; `view` in the tangent frame (need not be unit).
// Zero below the horizon or for a texel that is not compressed. Throws NotFoundError for a material
// index past the end.
Rgb albedo(const Decoder& decoder, size_t material, int x, int y, const Vec3& view);

}  // namespace btfvq
