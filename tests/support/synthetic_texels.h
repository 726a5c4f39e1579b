#pragma once
// Resampled texels generated directly on the angular grid from an analytic, spatially varying
// material: a few material classes (diffuse colour + one specular lobe) whose brightness, lobe width
// and colour vary per texel, plus deterministic noise. Small and fast, for encoder tests.
#include <cmath>
#include <cstdint>
#include <vector>

#include "pipeline/btf.h"
#include <btfvq/colour.h>
#include <btfvq/directions.h>
#include "pipeline/parametrization.h"
#include "pipeline/encode/schedule.h"

namespace btfvq::test {

inline uint32_t hash32(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352dU;
  x ^= x >> 15;
  x *= 0x846ca68bU;
  x ^= x >> 16;
  return x;
}
inline float unit_hash(uint32_t a, uint32_t b) { return float(hash32(a * 2654435761U ^ hash32(b)) >> 8) / 16777216.0f; }

struct SyntheticMaterial {
  AngularGrid grid;
  Dynamic dyn = Dynamic::LDR;
  int width = 16, height = 16;
  int classes = 3;
  float noise = 1.0f;  // RGB units (LDR) / relative (HDR)
  uint32_t seed = 1;

  std::vector<float> cos_i, spec;  // per sample: light cosine, cosine to the mirror direction

  SyntheticMaterial(int w, int h, Dynamic d = Dynamic::LDR, AngularGrid g = {}) : grid(g), dyn(d), width(w), height(h) {
    const size_t n = grid.samples();
    cos_i.resize(n);
    spec.resize(n);
    for (int p = 0; p < grid.n_phi_v; ++p)
      for (int t = 0; t < grid.n_theta_v; ++t) {
        const Direction view{grid.theta_v_node(t), grid.phi_v_node(p)};
        const Vec3 v = to_vector(view);
        const Vec3 r{-v.x, -v.y, v.z};
        for (int a = 0; a < grid.n_alpha; ++a)
          for (int b = 0; b < grid.n_beta; ++b) {
            const Vec3 l = to_vector(from_onion({grid.alpha_node(a), grid.beta_node(b)}, view.phi));
            const size_t i = grid.index(p, t, a, b);
            cos_i[i] = float(std::max(0.0, l.z));
            spec[i] = float(std::max(0.0, l.x * r.x + l.y * r.y + l.z * r.z));
          }
      }
  }

  // Coding-space texel: out[c * samples + i].
  void texel(uint32_t id, float* out) const {
    const int x = int(id % uint32_t(width)), y = int(id / uint32_t(width));
    const int cls = ((x / 4) + 2 * (y / 4)) % classes;
    static const float albedo[4][3] = {{0.55f, 0.35f, 0.25f}, {0.3f, 0.45f, 0.6f}, {0.5f, 0.5f, 0.45f}, {0.2f, 0.5f, 0.25f}};
    static const float lobe[4] = {20.0f, 60.0f, 6.0f, 35.0f};
    static const float strength[4] = {0.6f, 0.9f, 0.25f, 0.5f};
    const float bright = 0.6f + 0.7f * unit_hash(id, seed);
    const float width_k = lobe[cls] * (0.7f + 0.6f * unit_hash(id, seed + 1));
    const float tint = 0.9f + 0.2f * unit_hash(id, seed + 2);
    const size_t n = grid.samples();
    for (size_t i = 0; i < n; ++i) {
      const float s = strength[cls] * std::exp(-width_k * (1.0f - spec[i]));
      float rgb[3];
      for (int c = 0; c < 3; ++c) {
        const float al = albedo[cls][c] * (c == 0 ? tint : 1.0f);
        const float nz = noise * (unit_hash(id * 7919U + uint32_t(c), uint32_t(i) + seed) - 0.5f);
        rgb[c] = (bright * (al * cos_i[i] + s)) * (dyn == Dynamic::LDR ? 230.0f : 3.0f) +
                 (dyn == Dynamic::LDR ? nz : nz * 0.01f);
        if (dyn == Dynamic::LDR) rgb[c] = std::clamp(rgb[c], 0.0f, 255.0f);
        else rgb[c] = std::max(rgb[c], 0.0f);
      }
      const Lab3 v = to_coding_space({rgb[0], rgb[1], rgb[2]}, dyn == Dynamic::HDR);
      out[i] = v.l;
      out[n + i] = v.a;
      out[2 * n + i] = v.b;
    }
  }

  std::vector<float> texel(uint32_t id) const {
    std::vector<float> v(3 * grid.samples());
    texel(id, v.data());
    return v;
  }

  TexelSource source() const {
    return [this](const uint32_t* ids, size_t n, float* out) {
      for (size_t k = 0; k < n; ++k) texel(ids[k], out + k * 3 * grid.samples());
    };
  }
};

}  // namespace btfvq::test
