#include "pipeline/encode/ceiling.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <btfvq/error.h>
#include "pipeline/encode/resample.h"
#include "pipeline/util/parallel.h"

namespace btfvq {

Rgb evaluate_resampled(const float* tx, const AngularGrid& grid, const Direction& light, const Direction& view) {
  if (!(light.theta <= 90.0 && view.theta <= 90.0)) return {};
  const int nb = grid.n_beta;
  const size_t samples = grid.samples();
  // Onion angles and cells as Decoder::evaluate_p4 computes them.
  const double phi = relative_light_azimuth(light.phi, view.phi) * kDeg, sin_t = std::sin(light.theta * kDeg);
  const double sb = std::clamp(std::cos(phi) * sin_t, -1.0, 1.0), ly = std::sin(phi) * sin_t;
  const double cos_b = std::sqrt(1.0 - sb * sb);
  const double alpha = cos_b > 0 ? std::asin(std::clamp(ly / cos_b, -1.0, 1.0)) / kDeg : 0.0, beta = std::asin(sb) / kDeg;
  const int bi = std::clamp(int(std::floor((sb + 1.0) / 2.0 * (nb - 1))), 0, nb - 2);
  const double b0 = grid.beta_node(bi), b1 = grid.beta_node(bi + 1);
  const double bw = std::clamp((beta - b0) / (b1 - b0), 0.0, 1.0);
  const Cell ac = grid.alpha_cell(alpha), tc = grid.theta_v_cell(view.theta), pc = grid.phi_v_cell(view.phi);
  // The decoder's cubic Hermite along beta, with its one-sided end tangents.
  const double h01 = -2 * bw * bw * bw + 3 * bw * bw, h00 = 1 - h01, h11 = bw * bw * bw - bw * bw, h10 = h11 - bw * bw + bw;
  auto hermite = [&](const float* s) {
    const double p0 = s[bi], p1 = s[bi + 1];
    const double m0 = bi == 0 ? p1 - p0 : (p1 - double(s[bi - 1])) / 2;
    const double m1 = bi == nb - 2 ? p1 - p0 : (double(s[bi + 1]) - p0) / 2;
    return h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1;
  };
  const int alpha_node[2] = {ac.i0, ac.i1};
  const double alpha_w[2] = {1.0 - ac.w, ac.w};
  const int phi_node[2] = {pc.i0, pc.i1};
  const double phi_w[2] = {1.0 - pc.w, pc.w};
  const int theta_node[2] = {tc.i0, tc.i1};
  const double theta_w[2] = {tc.i0 == tc.i1 ? 1.0 : 1.0 - tc.w, tc.i0 == tc.i1 ? 0.0 : tc.w};
  double r = 0, g = 0, b = 0;
  for (int p = 0; p < 2; ++p) {
    if (phi_w[p] == 0.0) continue;
    for (int t = 0; t < 2; ++t) {
      if (theta_w[t] == 0.0) continue;
      double yy = 0, cb = 0, cr = 0;
      for (int a = 0; a < 2; ++a) {
        const size_t base = grid.index(phi_node[p], theta_node[t], alpha_node[a], 0);
        const double w = alpha_w[a];
        yy += w * hermite(tx + base);
        cb += w * ((1.0 - bw) * double(tx[samples + base + size_t(bi)]) + bw * double(tx[samples + base + size_t(bi) + 1]));
        cr += w * ((1.0 - bw) * double(tx[2 * samples + base + size_t(bi)]) +
                   bw * double(tx[2 * samples + base + size_t(bi) + 1]));
      }
      const Rgb v = from_coding_space({float(yy), float(cb), float(cr)}, false);
      const double s = phi_w[p] * theta_w[t];
      r += s * double(v.r);
      g += s * double(v.g);
      b += s * double(v.b);
    }
  }
  return {float(r), float(g), float(b)};
}

MeasuredSample parametrization_roundtrip(const MeasuredSample& sample, const ParameterDictionary& config) {
  if (sample.is_hdr()) throw InputError("parametrization round trip: only LDR samples are supported");
  const ResampleOperator op(sample, grid_settings(config), ResampleSettings::from(config));
  const AngularGrid& grid = op.grid();
  std::vector<std::vector<Direction>> lights;
  for (size_t v = 0; v < sample.view_count(); ++v) lights.push_back(sample.lights(v));
  MeasuredSample out(sample.width(), sample.height(), sample.views(), lights, Dynamic::LDR);
  // Resampling a tile is cheap beside evaluating its texels at every pair: the tile is resampled on
  // the calling thread and its texels are evaluated on all of them.
  constexpr size_t kTile = 256;
  const size_t pairs = sample.pair_count(), values = op.values_per_texel();
  std::vector<float> tile(kTile * values);
  for (size_t first = 0; first < sample.texel_count(); first += kTile) {
    const size_t n = std::min(kTile, sample.texel_count() - first);
    op.apply(sample, first, n, tile.data());
    parallel_for(0, n, [&](size_t i) {
      for (size_t v = 0; v < sample.view_count(); ++v)
        for (size_t l = 0; l < lights[v].size(); ++l) {
          const Rgb rgb = evaluate_resampled(tile.data() + i * values, grid, lights[v][l], sample.views()[v]);
          uint8_t* o = out.ldr_data().data() + ((first + i) * pairs + sample.pair_index(v, l)) * 3;
          o[0] = uint8_t(std::clamp(std::lround(rgb.r), 0L, 255L));
          o[1] = uint8_t(std::clamp(std::lround(rgb.g), 0L, 255L));
          o[2] = uint8_t(std::clamp(std::lround(rgb.b), 0L, 255L));
        }
    });
  }
  return out;
}

}  // namespace btfvq
