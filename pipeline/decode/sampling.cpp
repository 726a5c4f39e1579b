#include "pipeline/decode/sampling.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <btfvq/error.h>

namespace btfvq {

namespace {

constexpr double kUniformPdf = 1.0 / (2.0 * kPi);

int wrap(int v, int n) {
  const int r = v % n;
  return r < 0 ? r + n : r;
}

// Position t in [0, 1] inside a cell whose density is linear from d0 to d1 (cell width h) at which
// the cell's CDF reaches `mass`: h (d0 t + (d1 - d0) t^2 / 2) = mass. The rationalised root is
// stable for d1 == d0 and continuous in mass, d0 and d1.
double invert_linear_cell(double d0, double d1, double h, double mass) {
  const double u = std::max(mass, 0.0) / h;
  const double disc = std::max(d0 * d0 + 2.0 * (d1 - d0) * u, 0.0);
  const double den = d0 + std::sqrt(disc);
  if (!(den > 0)) return 0.0;
  return std::clamp(2.0 * u / den, 0.0, 1.0);
}

}  // namespace

double sampling_luminance(const Rgb& c, bool hdr) {
  if (hdr) return 0.2126729 * c.r + 0.7151522 * c.g + 0.0721750 * c.b;
  return 0.299 * c.r + 0.587 * c.g + 0.114 * c.b;
}

struct LightSampler::Mixture {
  bool uniform = true;  // no reflectance: sample the hemisphere uniformly
  bool hdr = false;
  int n = 0;
  double w[4] = {};
  uint32_t p2[4] = {};
  double floor = 0;
  // The onion frame of the view: sin(beta) = l . e1, sin(alpha) cos(beta) = l . e2 (paper eq. 2,
  // rotated by phi_v + 90 degrees as the decoder's azimuth convention).
  Vec3 e1, e2;
};

LightSampler::LightSampler(const Decoder& decoder) : decoder_(decoder) {
  const Database& db = decoder.database();
  const Codebooks& k = db.codebooks;
  na_ = k.grid.n_alpha;
  nb_ = k.grid.n_beta;
  nt_ = k.grid.n_theta_v;
  np_ = k.grid.n_phi_v;
  d_alpha_ = kPi / (na_ - 1);
  d_s_ = 2.0 / (nb_ - 1);
  bool used[2] = {false, false};
  for (const Material& m : db.materials) used[m.dynamic == Dynamic::HDR ? 1 : 0] = true;
  const size_t n_p2 = k.p2_index.rows(), cells = size_t(na_) * size_t(nb_);
  for (int h = 0; h < 2; ++h) {
    if (!used[h]) continue;
    node_lum_[h].resize(n_p2 * cells);
    row_int_[h].resize(n_p2 * size_t(na_));
    mean_lum_[h].resize(n_p2);
    total_[h].resize(n_p2);
    for (size_t p2 = 0; p2 < n_p2; ++p2) {
      float* nodes = node_lum_[h].data() + p2 * cells;
      double total = 0;
      for (int a = 0; a < na_; ++a) {
        const float* p1 = k.p1.row(k.p2_index.at(p2, size_t(a)));
        const double scale = double(k.p2_scale.at(p2, size_t(a)));
        double row = 0;
        for (int b = 0; b < nb_; ++b) {
          const double y = scale * double(p1[b]);
          // The luminance of the M entry's RGB at this node (sampling_luminance of the decoded value).
          const double lum = std::max(h ? y : (y - 16.0) * 255.0 / 219.0, 0.0);
          nodes[size_t(a) * size_t(nb_) + size_t(b)] = float(lum);
          row += (b == 0 || b == nb_ - 1) ? 0.5 * lum : lum;
          total += lum;
        }
        row_int_[h][p2 * size_t(na_) + size_t(a)] = float(row * d_s_);
      }
      mean_lum_[h][p2] = float(total / double(cells));
      const float* r = row_int_[h].data() + p2 * size_t(na_);
      double area = 0;
      for (int a = 0; a + 1 < na_; ++a) area += 0.5 * d_alpha_ * (double(r[a]) + double(r[a + 1]));
      total_[h][p2] = area;
    }
  }
  view_nodes_.resize(k.p4_index.rows() * size_t(np_) * size_t(nt_));
  for (size_t p4 = 0; p4 < k.p4_index.rows(); ++p4)
    for (int p = 0; p < np_; ++p) {
      const uint32_t p3 = k.p4_index.at(p4, size_t(p));
      for (int t = 0; t < nt_; ++t)
        view_nodes_[(p4 * size_t(np_) + size_t(p)) * size_t(nt_) + size_t(t)] = {
            k.m.at(k.p3_index.at(p3, size_t(t)), 0), k.p4_scale.at(p4, size_t(p)) * k.p3_scale.at(p3, size_t(t))};
    }
}

const float* LightSampler::nodes(uint32_t p2, bool hdr) const {
  return node_lum_[hdr ? 1 : 0].data() + size_t(p2) * size_t(na_) * size_t(nb_);
}
const float* LightSampler::rows(uint32_t p2, bool hdr) const {
  return row_int_[hdr ? 1 : 0].data() + size_t(p2) * size_t(na_);
}

LightSampler::Mixture LightSampler::mixture(size_t material, int x, int y, const Vec3& view) const {
  const Database& db = decoder_.database();
  if (material >= db.materials.size())
    throw NotFoundError("material index " + std::to_string(material) + " is past the end of the database (" +
                        std::to_string(db.materials.size()) + " materials)");
  Mixture mx;
  const double len = std::sqrt(view.x * view.x + view.y * view.y + view.z * view.z);
  // Written so that NaN components also give the uniform fallback.
  if (!(len > 0) || !(view.z >= 0) || !std::isfinite(len)) return mx;
  const double rho = std::sqrt(view.x * view.x + view.y * view.y);
  const double cp = rho > 0 ? view.x / rho : 1.0, sp = rho > 0 ? view.y / rho : 0.0;
  mx.e1 = {-sp, cp, 0};
  mx.e2 = {-cp, -sp, 0};

  const Material& mat = db.materials[material];
  if (mat.width <= 0 || mat.height <= 0) return mx;
  const size_t texel = size_t(wrap(y, mat.height)) * size_t(mat.width) + size_t(wrap(x, mat.width));
  const int32_t p4_row = mat.p6_index[texel];
  if (p4_row < 0) return mx;  // (the P6 scale only scales the reflectance; the density ignores it)
  mx.hdr = mat.dynamic == Dynamic::HDR;

  // The decoder's view blend (docs/btfbase-format.md step 6): P4 over phi_v, P3 over theta_v, with their scales.
  const AngularGrid& g = db.codebooks.grid;
  double phi_v = std::atan2(view.y, view.x) / kDeg;
  if (phi_v < 0) phi_v += 360;
  const double theta_v = std::acos(std::clamp(view.z / len, -1.0, 1.0)) / kDeg;
  const Cell tc = g.theta_v_cell(theta_v), pc = g.phi_v_cell(phi_v);
  const int phi_node[2] = {pc.i0, pc.i1};
  const double phi_w[2] = {1.0 - pc.w, pc.w};
  const int theta_node[2] = {tc.i0, tc.i1};
  const double theta_w[2] = {tc.i0 == tc.i1 ? 1.0 : 1.0 - tc.w, tc.i0 == tc.i1 ? 0.0 : tc.w};
  double mean = 0;
  const ViewNode* row = view_nodes_.data() + size_t(p4_row) * size_t(np_) * size_t(nt_);
  for (int p = 0; p < 2; ++p) {
    if (!(phi_w[p] > 0)) continue;
    for (int t = 0; t < 2; ++t) {
      if (!(theta_w[t] > 0)) continue;
      const ViewNode& node = row[size_t(phi_node[p]) * size_t(nt_) + size_t(theta_node[t])];
      const double w = phi_w[p] * theta_w[t] * double(node.scale);
      if (!(w > 0)) continue;  // a negative blend weight cannot be a density; such entries are dropped
      // The entry's tables are read right after this; start fetching them now, in parallel (the
      // marginal needs the row integrals, the conditional two rows of nodes not known yet).
      const float* nodes_q = nodes(node.p2, mx.hdr);
      for (size_t off = 0; off < size_t(na_) * size_t(nb_); off += 16) __builtin_prefetch(nodes_q + off);
      __builtin_prefetch(rows(node.p2, mx.hdr));
      mx.w[mx.n] = w;
      mx.p2[mx.n] = node.p2;
      ++mx.n;
      mean += w * double(mean_lum_[mx.hdr ? 1 : 0][node.p2]);
    }
  }
  if (!(mean > 0)) return mx;
  mx.floor = kSamplingFloor * mean;
  mx.uniform = false;
  return mx;
}

double LightSampler::normaliser(const Mixture& mx) const {
  // Z = integral of f over the (alpha, s) square: luminance x (1 + column floor) + floor x area 2 pi.
  double z = 0;
  for (int i = 0; i < mx.n; ++i) z += mx.w[i] * total_[mx.hdr ? 1 : 0][mx.p2[i]];
  return (1.0 + kSamplingColumnFloor) * z + 2.0 * kPi * mx.floor;
}

LightSample LightSampler::sample(size_t material, int x, int y, const Vec3& view, double xi1, double xi2) const {
  const Mixture mx = mixture(material, x, y, view);
  xi1 = std::isfinite(xi1) ? std::clamp(xi1, 0.0, 1.0) : 0.0;
  xi2 = std::isfinite(xi2) ? std::clamp(xi2, 0.0, 1.0) : 0.0;
  if (mx.uniform) {
    // Uniform in (alpha, sin beta) is uniform in solid angle (d omega = d alpha ds).
    const double alpha = (xi1 - 0.5) * kPi, s = 2.0 * xi2 - 1.0, cb = std::sqrt(std::max(0.0, 1.0 - s * s));
    const Vec3 l{s, std::sin(alpha) * cb, std::cos(alpha) * cb};
    // No view frame below the horizon: the local onion frame is the tangent frame itself.
    return {l, kUniformPdf};
  }
  const size_t na = size_t(na_), nb = size_t(nb_);
  // Stack scratch for the usual grids; a larger grid pays one allocation per call.
  double stack[192];
  std::vector<double> heap;
  double* buf = stack;
  if (2 * na + nb > 192) {
    heap.resize(2 * na + nb);
    buf = heap.data();
  }
  double* lum = buf;     // integral over s of the luminance at the alpha nodes
  double* r = lum + na;         // marginal density over alpha at the nodes (integral over s of f)
  double* gcol = r + na;        // conditional density over s at the sampled alpha
  for (size_t a = 0; a < na; ++a) lum[a] = 0;
  for (int i = 0; i < mx.n; ++i) {
    const float* ri = rows(mx.p2[i], mx.hdr);
    for (size_t a = 0; a < na; ++a) lum[a] += mx.w[i] * double(ri[a]);
  }
  // f = luminance + floor + column floor (kSamplingColumnFloor x the column's mean over s, length 2).
  for (size_t a = 0; a < na; ++a) r[a] = (1.0 + kSamplingColumnFloor) * lum[a] + 2.0 * mx.floor;
  const double z = normaliser(mx);

  // alpha: the cell by the marginal CDF, then the position inside it.
  double target = xi1 * z, cum = 0;
  size_t ka = 0;
  for (;; ++ka) {
    const double mass = 0.5 * d_alpha_ * (r[ka] + r[ka + 1]);
    if (target <= cum + mass || ka + 2 == na) break;
    cum += mass;
  }
  const double ta = invert_linear_cell(r[ka], r[ka + 1], d_alpha_, target - cum);

  // beta (as s = sin beta): the density along s at this alpha, linear between the alpha nodes.
  const double column_floor = 0.5 * kSamplingColumnFloor * ((1.0 - ta) * lum[ka] + ta * lum[ka + 1]);
  for (size_t b = 0; b < nb; ++b) gcol[b] = mx.floor + column_floor;
  for (int i = 0; i < mx.n; ++i) {
    const float* n0 = nodes(mx.p2[i], mx.hdr) + ka * nb;
    const float* n1 = n0 + nb;
    const double w0 = mx.w[i] * (1.0 - ta), w1 = mx.w[i] * ta;
    for (size_t b = 0; b < nb; ++b) gcol[b] += w0 * double(n0[b]) + w1 * double(n1[b]);
  }
  double total = 0;
  for (size_t b = 0; b + 1 < nb; ++b) total += 0.5 * d_s_ * (gcol[b] + gcol[b + 1]);
  target = xi2 * total;
  cum = 0;
  size_t kb = 0;
  for (;; ++kb) {
    const double mass = 0.5 * d_s_ * (gcol[kb] + gcol[kb + 1]);
    if (target <= cum + mass || kb + 2 == nb) break;
    cum += mass;
  }
  const double tb = invert_linear_cell(gcol[kb], gcol[kb + 1], d_s_, target - cum);

  const double alpha = -0.5 * kPi + (double(ka) + ta) * d_alpha_;
  const double s = std::clamp(-1.0 + (double(kb) + tb) * d_s_, -1.0, 1.0);
  const double cb = std::sqrt(std::max(0.0, 1.0 - s * s));
  const double ly = std::sin(alpha) * cb, lz = std::cos(alpha) * cb;
  const Vec3 d{s * mx.e1.x + ly * mx.e2.x, s * mx.e1.y + ly * mx.e2.y, std::max(lz, 0.0)};
  // At the poles A and B (sin beta = +-1) every alpha is the same direction; pdf() reads them at
  // alpha = 0, and the sample reports the same value so that the two always agree.
  if (!(cb > 0)) return {d, pdf(material, x, y, d, view)};
  const double f = (1.0 - tb) * gcol[kb] + tb * gcol[kb + 1];
  return {d, f / z};
}

double LightSampler::pdf(size_t material, int x, int y, const Vec3& light, const Vec3& view) const {
  const Mixture mx = mixture(material, x, y, view);
  const double len = std::sqrt(light.x * light.x + light.y * light.y + light.z * light.z);
  if (!(len > 0) || !(light.z >= 0) || !std::isfinite(len)) return 0.0;
  if (mx.uniform) return kUniformPdf;
  const double lx = (light.x * mx.e1.x + light.y * mx.e1.y) / len;
  const double ly = (light.x * mx.e2.x + light.y * mx.e2.y) / len;
  const double lz = light.z / len;
  const double s = std::clamp(lx, -1.0, 1.0);
  const double alpha = (ly == 0 && lz == 0) ? 0.0 : std::atan2(ly, lz);
  const int ka = std::clamp(int(std::floor((alpha + 0.5 * kPi) / d_alpha_)), 0, na_ - 2);
  const int kb = std::clamp(int(std::floor((s + 1.0) / d_s_)), 0, nb_ - 2);
  const double ta = std::clamp((alpha + 0.5 * kPi) / d_alpha_ - ka, 0.0, 1.0);
  const double tb = std::clamp((s + 1.0) / d_s_ - kb, 0.0, 1.0);
  const size_t nb = size_t(nb_);
  double f = mx.floor, column = 0;
  for (int i = 0; i < mx.n; ++i) {
    const float* n0 = nodes(mx.p2[i], mx.hdr) + size_t(ka) * nb + size_t(kb);
    const float* n1 = n0 + nb;
    f += mx.w[i] * ((1.0 - ta) * ((1.0 - tb) * n0[0] + tb * n0[1]) + ta * ((1.0 - tb) * n1[0] + tb * n1[1]));
    const float* ri = rows(mx.p2[i], mx.hdr);
    column += mx.w[i] * ((1.0 - ta) * double(ri[ka]) + ta * double(ri[ka + 1]));
  }
  f += 0.5 * kSamplingColumnFloor * column;
  return f / normaliser(mx);
}

}  // namespace btfvq
