#include "pipeline/metrics/btf_cielab.h"

#include <algorithm>
#include <array>
#include <bit>
#include <chrono>
#include <cmath>
#include <complex>
#include <cstring>

#include <btfvq/error.h>
#include "pipeline/metrics/fft.h"
#include "pipeline/metrics/metrics.h"
#include "pipeline/util/parallel.h"

namespace btfvq {

namespace {

constexpr double kPiD = 3.14159265358979323846;

// Paper Table 1 (weights; sigma in degrees of visual angle; delta in seconds).
const std::vector<CsfComponent> kComponents{
    {CsfChannel::Achromatic, 2.05962, 0.058406, 0.025135},
    {CsfChannel::Achromatic, 1.29338, 0.038015, 0.054688},
    {CsfChannel::Achromatic, -2.35300, 0.140856, 0.090229},
    {CsfChannel::Chromatic, 0.67965, 0.096652, 0.069195},
    {CsfChannel::Chromatic, 0.32035, 0.054198, 0.031830},
};

// Cone responses from XYZ: the Hunt-Pointer-Estevez matrix normalised to D65 (D65 white gives
// L = M = S = 1 to 4 digits), as in Fairchild, "Color Appearance Models", and Reinhard et al. 2001.
constexpr double kXyzToLms[9] = {0.4002, 0.7076, -0.0808, -0.2263, 1.1653, 0.0457, 0.0, 0.0, 0.9182};
// Cone response of the display's black, relative to white (a 1000:1 display): keeps log(0) finite.
constexpr float kDark = 1e-3f;

// The seven filtered images of one direction pair of one sample: (component, opponent channel).
struct ChannelComponent {
  int component;  // index into kComponents
  int channel;    // 0 l, 1 alpha, 2 beta
};
constexpr std::array<ChannelComponent, 7> kChannels{{{0, 0}, {1, 0}, {2, 0}, {3, 1}, {4, 1}, {3, 2}, {4, 2}}};
// They are filtered four at a time as complex images: (real, imaginary) channel indices, -1 = zero.
constexpr std::array<std::array<int, 2>, 4> kPacking{{{0, 1}, {2, -1}, {3, 5}, {4, 6}}};
constexpr size_t kTile = 16;  // texels per cache line of floats

using Mat3 = std::array<double, 9>;

Mat3 multiply(const double* a, const double* b) {
  Mat3 r{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k) r[size_t(3 * i + j)] += a[3 * i + k] * b[3 * k + j];
  return r;
}

Mat3 inverse(const Mat3& m) {
  const double det = m[0] * (m[4] * m[8] - m[5] * m[7]) - m[1] * (m[3] * m[8] - m[5] * m[6]) +
                     m[2] * (m[3] * m[7] - m[4] * m[6]);
  Mat3 r{(m[4] * m[8] - m[5] * m[7]), -(m[1] * m[8] - m[2] * m[7]), (m[1] * m[5] - m[2] * m[4]),
         -(m[3] * m[8] - m[5] * m[6]), (m[0] * m[8] - m[2] * m[6]), -(m[0] * m[5] - m[2] * m[3]),
         (m[3] * m[7] - m[4] * m[6]), -(m[0] * m[7] - m[1] * m[6]), (m[0] * m[4] - m[1] * m[3])};
  for (double& v : r) v /= det;
  return r;
}

// Display values <-> l-alpha-beta. The opponent axes of Ruderman et al. on log cone responses,
// here in log2 units: every step between this transform and its inverse is linear, so the base of
// the logarithm does not change the result.
class ColourModel {
 public:
  ColourModel() {
    const Mat3 rgb_to_lms = multiply(kXyzToLms, kSrgbToXyz);
    for (size_t i = 0; i < 9; ++i) rgb_to_lms_[i] = float(rgb_to_lms[i]);
    Mat3 xyz_to_lms;
    std::copy(std::begin(kXyzToLms), std::end(kXyzToLms), xyz_to_lms.begin());
    lms_to_xyz_ = inverse(xyz_to_lms);
    for (int i = 0; i < 256; ++i) table_[size_t(i)] = float(srgb8_to_linear(float(i)));
  }

  // Linear value of an 8-bit code.
  float linear(uint8_t v) const { return table_[v]; }
  // HDR: the tone-mapped display value, linearised as an LDR code would be.
  static float linear_hdr(float v) { return float(srgb8_to_linear(display_value(v, Dynamic::HDR))); }

  // kTile colours given as linear r, g, b arrays to l, alpha, beta arrays (vectorisable).
  void from_linear(const float* __restrict r, const float* __restrict g, const float* __restrict b,
                   float* __restrict l, float* __restrict alpha, float* __restrict beta) const {
    const float m[9] = {rgb_to_lms_[0], rgb_to_lms_[1], rgb_to_lms_[2], rgb_to_lms_[3], rgb_to_lms_[4],
                        rgb_to_lms_[5], rgb_to_lms_[6], rgb_to_lms_[7], rgb_to_lms_[8]};
    for (size_t i = 0; i < kTile; ++i) {
      const float L = log2_approx(std::max(m[0] * r[i] + m[1] * g[i] + m[2] * b[i], 0.0f) + kDark);
      const float M = log2_approx(std::max(m[3] * r[i] + m[4] * g[i] + m[5] * b[i], 0.0f) + kDark);
      const float S = log2_approx(std::max(m[6] * r[i] + m[7] * g[i] + m[8] * b[i], 0.0f) + kDark);
      l[i] = (L + M + S) * float(1 / kSqrt3);
      alpha[i] = (L + M - 2 * S) * float(1 / kSqrt6);
      beta[i] = (L - M) * float(1 / kSqrt2);
    }
  }

  CieLab to_lab(float l, float a, float b) const {
    const double ll = l / kSqrt3, aa = a / kSqrt6, bb = b / kSqrt2;
    const double L = std::max(double(std::exp2(float(ll + aa + bb))) - double(kDark), 0.0);
    const double M = std::max(double(std::exp2(float(ll + aa - bb))) - double(kDark), 0.0);
    const double S = std::max(double(std::exp2(float(ll - 2 * aa))) - double(kDark), 0.0);
    const Mat3& m = lms_to_xyz_;
    return xyz_to_lab(m[0] * L + m[1] * M + m[2] * S, m[3] * L + m[4] * M + m[5] * S, m[6] * L + m[7] * M + m[8] * S);
  }

 private:
  static constexpr double kSqrt2 = 1.4142135623730951, kSqrt3 = 1.7320508075688772, kSqrt6 = 2.449489742783178;

  // log2 of a positive normal float to 5e-8: exponent, mantissa in [sqrt 1/2, sqrt 2), and
  // 2 atanh((m - 1) / (m + 1)) / ln 2 to the t^7 term. Inline and branch-free, unlike log2f.
  static float log2_approx(float x) {
    const uint32_t bits = std::bit_cast<uint32_t>(x);
    const float m0 = std::bit_cast<float>((bits & 0x7FFFFFu) | 0x3F800000u);
    const bool big = m0 > 1.41421356f;
    const float m = big ? 0.5f * m0 : m0;
    const float e = float(int32_t(bits >> 23) - 127) + (big ? 1.0f : 0.0f);
    const float t = (m - 1.0f) / (m + 1.0f), t2 = t * t;
    return e + t * (2.88539008f + t2 * (0.961796694f + t2 * (0.577078016f + t2 * 0.412198583f)));
  }

  std::array<float, 9> rgb_to_lms_{};
  Mat3 lms_to_xyz_{};
  std::array<float, 256> table_{};
};

void check_geometry(const MeasuredSample& r, const MeasuredSample& t) {
  if (r.width() != t.width() || r.height() != t.height())
    throw InputError("BTF-CIELab: spatial sizes differ");
  if (r.dynamic() != t.dynamic()) throw InputError("BTF-CIELab: one sample is LDR and the other HDR");
  if (r.views() != t.views()) throw InputError("BTF-CIELab: view directions differ");
  if (r.texel_count() == 0 || r.pair_count() == 0) throw InputError("BTF-CIELab: sample has no images");
  for (size_t v = 0; v < r.view_count(); ++v) {
    if (r.lights(v) != t.lights(v)) throw InputError("BTF-CIELab: light directions of view " + std::to_string(v) + " differ");
    if (r.lights(v) != r.lights(0))
      throw InputError("BTF-CIELab: view " + std::to_string(v) +
                       " has its own light list; the angular filter needs one light list shared by all views");
  }
}

// Frequency of DFT index k of n, in cycles per sample, in [-1/2, 1/2).
double frequency(size_t k, size_t n) { return (k < (n + 1) / 2 ? double(k) : double(k) - double(n)) / double(n); }

}  // namespace

ViewingCondition parse_viewing_condition(const std::string& text) {
  ViewingCondition c;
  const auto comma = text.find(',');
  const std::string res = text.substr(0, comma), speed = comma == std::string::npos ? "" : text.substr(comma + 1);
  auto number = [&](const std::string& s, const char* what) {
    size_t used = 0;
    double v = 0;
    try {
      v = std::stod(s, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used != s.size() || !std::isfinite(v))
      throw InputError("BTF-CIELab viewing condition '" + text + "': " + what + " '" + s + "' is not a number");
    return v;
  };
  if (!res.empty()) c.resolution = number(res, "resolution");
  if (!speed.empty()) c.speed = number(speed, "speed");
  if (!(c.resolution > 0)) throw InputError("BTF-CIELab viewing condition '" + text + "': the resolution must be positive");
  if (!(c.speed >= 0)) throw InputError("BTF-CIELab viewing condition '" + text + "': the speed must not be negative");
  return c;
}

const std::vector<CsfComponent>& btf_cielab_components() { return kComponents; }

double csf_spatial_gain(CsfChannel channel, double f) {
  double g = 0;
  for (const auto& c : kComponents)
    if (c.channel == channel) g += c.weight * std::exp(-kPiD * kPiD * c.sigma_degrees * c.sigma_degrees * f * f);
  return g;
}

std::vector<double> solid_angle_weights(const std::vector<Direction>& dirs) {
  const size_t n = dirs.size();
  std::vector<double> w(n, 0.0);
  if (n == 0) return w;
  std::vector<Vec3> v(n);
  for (size_t i = 0; i < n; ++i) v[i] = to_vector(dirs[i]);
  // A Fibonacci lattice of equal-area points on the upper hemisphere; each point counts for its
  // nearest direction (ties go to the smaller (theta, phi), so the order of dirs does not matter).
  constexpr size_t kPoints = 16384;
  const double golden = kPiD * (3.0 - std::sqrt(5.0));
  for (size_t k = 0; k < kPoints; ++k) {
    const double z = 1.0 - (double(k) + 0.5) / double(kPoints), r = std::sqrt(std::max(0.0, 1.0 - z * z));
    const double phi = golden * double(k);
    const Vec3 p{r * std::cos(phi), r * std::sin(phi), z};
    size_t best = 0;
    double best_dot = -2;
    for (size_t i = 0; i < n; ++i) {
      const double d = p.x * v[i].x + p.y * v[i].y + p.z * v[i].z;
      const bool tie = d == best_dot && (dirs[i].theta < dirs[best].theta ||
                                         (dirs[i].theta == dirs[best].theta && dirs[i].phi < dirs[best].phi));
      if (d > best_dot || tie) {
        best_dot = d;
        best = i;
      }
    }
    w[best] += 1.0;
  }
  double sum = 0;
  for (double& x : w) sum += (x = std::max(x, 0.5));  // a direction no point reached keeps a little weight
  for (double& x : w) x /= sum;
  return w;
}

AngularKernel angular_kernel(const std::vector<Direction>& dirs, double width) {
  const size_t n = dirs.size();
  AngularKernel k;
  k.rows.resize(n);
  if (!(width > 0)) {
    for (size_t a = 0; a < n; ++a) k.rows[a] = {{uint32_t(a), 1.0f}};
    return k;
  }
  const std::vector<double> area = solid_angle_weights(dirs);
  for (size_t a = 0; a < n; ++a) {
    std::vector<std::pair<uint32_t, double>> row;
    double sum = 0;
    for (size_t b = 0; b < n; ++b) {
      const double angle = angle_between(dirs[a], dirs[b]) / kDeg;
      const double g = std::exp(-(angle / width) * (angle / width));
      if (g < kAngularCutoff) continue;
      row.push_back({uint32_t(b), g * area[b]});
      sum += g * area[b];
    }
    for (const auto& [b, g] : row) k.rows[a].push_back({b, float(g / sum)});
  }
  return k;
}

namespace {

// One run of btf_cielab(): the tables, then one pass per block of light directions.
class BtfCielab {
 public:
  BtfCielab(const MeasuredSample& r, const MeasuredSample& t, const BtfCielabOptions& o)
      : samples_{&r, &t},
        opt_(o),
        width_(size_t(r.width())),
        height_(size_t(r.height())),
        texels_(r.texel_count()),
        views_(r.views()),
        lights_(r.lights(0)),
        fft_(width_, height_),
        parallel_{.threads = size_t(std::max(1, o.threads))} {
    for (const auto& c : kComponents) {
      view_kernel_.push_back(angular_kernel(views_, c.delta_seconds * o.condition.speed));
      light_kernel_.push_back(angular_kernel(lights_, c.delta_seconds * o.condition.speed));
    }
    make_spatial_filters();
  }

  BtfCielabReport run() {
    const size_t nv = views_.size(), nl = lights_.size();
    const size_t per_light = nv * 2 * kChannels.size() * texels_ * sizeof(float);
    const size_t block = std::clamp<size_t>(opt_.memory_budget / std::max<size_t>(per_light, 1), 1, nl);
    filtered_.assign(block * per_light / sizeof(float), 0.0f);
    partial_.assign(nv * nl, {});
    BtfCielabReport rep;
    for (size_t l0 = 0; l0 < nl; l0 += block) {
      const size_t l1 = std::min(nl, l0 + block);
      filter_lights(l0, l1);
      filter_space(l1 - l0);
      compare(l0, l1);
      ++rep.light_blocks;
    }
    // Pooled in pair order, so the result does not depend on the threads or the block size.
    double weight = 0, s1 = 0, s2 = 0;
    for (size_t v = 0; v < nv; ++v) {
      const double w = std::cos(views_[v].theta * kDeg);
      for (size_t l = 0; l < nl; ++l) {
        const Partial& p = partial_[v * nl + l];
        weight += w * double(texels_);
        s1 += w * p.sum;
        s2 += w * p.sum_sq;
      }
    }
    rep.mean = s1 / weight;
    rep.rms = std::sqrt(s2 / weight);
    rep.stddev = std::sqrt(std::max(0.0, s2 / weight - rep.mean * rep.mean));
    rep.condition = opt_.condition;
    rep.pairs = nv * nl;
    rep.working_bytes = filtered_.size() * sizeof(float) + spatial_.size() * sizeof(float);
    return rep;
  }

 private:
  struct Partial {
    double sum = 0, sum_sq = 0;
  };

  // filtered_ image of (light in block, view, sample, channel).
  float* image(size_t lb, size_t v, size_t s, size_t c) {
    return filtered_.data() + (((lb * views_.size() + v) * 2 + s) * kChannels.size() + c) * texels_;
  }

  // Gaussian transfer of each component for each view, in the transposed layout of Fft2d, with the
  // inverse transform's 1 / (width height) folded in. Along the view's azimuth the texture appears
  // shrunk by cos(theta), so its frequencies there are seen 1 / cos(theta) times higher.
  void make_spatial_filters() {
    const size_t nv = views_.size();
    spatial_.resize(kComponents.size() * nv * texels_);
    const double r = opt_.condition.resolution, scale = 1.0 / double(texels_);
    parallel_for(0, kComponents.size() * nv, [&](size_t i) {
      const size_t k = i / nv, v = i % nv;
      const double sigma = kComponents[k].sigma_degrees * r;  // in texels
      const double c = std::max(std::cos(views_[v].theta * kDeg), 0.05);
      const double cp = std::cos(views_[v].phi * kDeg), sp = std::sin(views_[v].phi * kDeg);
      float* h = spatial_.data() + i * texels_;
      for (size_t kx = 0; kx < width_; ++kx)
        for (size_t ky = 0; ky < height_; ++ky) {
          const double fx = frequency(kx, width_), fy = frequency(ky, height_);
          const double fu = (fx * cp + fy * sp) / c, fp = -fx * sp + fy * cp;
          h[kx * height_ + ky] = float(scale * std::exp(-kPiD * kPiD * sigma * sigma * (fu * fu + fp * fp)));
        }
    }, parallel_);
  }

  const float* spatial(size_t k, size_t v) const { return spatial_.data() + (k * views_.size() + v) * texels_; }

  // Step 1: colour transform and the light-direction convolution of every component, per texel,
  // for the lights [l0, l1) of every view (the convolution commutes with the spatial filter, which
  // depends on the view only). Reads each texel's run of the texel-major store once per block.
  void filter_lights(size_t l0, size_t l1) {
    const size_t nl = lights_.size(), nv = views_.size(), pairs = nv * nl;
    std::vector<uint32_t> needed;
    {
      std::vector<bool> mark(nl, false);
      for (size_t l = l0; l < l1; ++l)
        for (const auto& kernel : light_kernel_)
          for (const auto& [b, g] : kernel.rows[l]) mark[b] = true;
      for (size_t b = 0; b < nl; ++b)
        if (mark[b]) needed.push_back(uint32_t(b));
    }
    std::vector<uint32_t> slot(nl, 0);  // light -> its place in `needed`
    for (size_t k = 0; k < needed.size(); ++k) slot[needed[k]] = uint32_t(k);
    const bool hdr = samples_[0]->is_hdr();
    const size_t nk = needed.size();
    // Texels go in tiles of kTile, so that every filtered image is written a cache line at a time.
    const size_t tiles = (texels_ + kTile - 1) / kTile;
    parallel_for(0, tiles, [&](size_t first, size_t last) {
      std::vector<float> rgb(nv * nk * 3 * kTile, 0.0f);  // [view][needed light][channel][texel of the tile]
      std::vector<float> lab(nk * 3 * kTile);             // [needed light][channel][texel of the tile]
      for (size_t tile = first; tile < last; ++tile) {
        const size_t t0 = tile * kTile, n = std::min(kTile, texels_ - t0);
        for (size_t s = 0; s < 2; ++s) {
          const MeasuredSample& m = *samples_[s];
          // Each texel's run of the texel-major store read front to back (views in order), the
          // linear colours kept for the tile.
          for (size_t i = 0; i < n; ++i)
            for (size_t v = 0; v < nv; ++v) {
              const size_t base = ((t0 + i) * pairs + v * nl) * 3;
              float* out = &rgb[v * nk * 3 * kTile + i];
              for (size_t k = 0; k < nk; ++k)
                for (size_t ch = 0; ch < 3; ++ch) {
                  const size_t at = base + 3 * needed[k] + ch;
                  out[(3 * k + ch) * kTile] = hdr ? ColourModel::linear_hdr(m.hdr_data()[at]) : colour_.linear(m.ldr_data()[at]);
                }
            }
          for (size_t v = 0; v < nv; ++v) {
            for (size_t k = 0; k < nk; ++k) {
              const float* src = &rgb[(v * nk + k) * 3 * kTile];
              float* dst = &lab[3 * k * kTile];
              colour_.from_linear(src, src + kTile, src + 2 * kTile, dst, dst + kTile, dst + 2 * kTile);
            }
            for (size_t l = l0; l < l1; ++l)
              for (size_t c = 0; c < kChannels.size(); ++c) {
                const auto& row = light_kernel_[size_t(kChannels[c].component)].rows[l];
                const size_t ch = size_t(kChannels[c].channel);
                float acc[kTile] = {};
                for (const auto& [b, g] : row) {
                  const float* x = &lab[(3 * slot[b] + ch) * kTile];
                  for (size_t i = 0; i < kTile; ++i) acc[i] += g * x[i];
                }
                std::copy(acc, acc + n, image(l - l0, v, s, c) + t0);
              }
          }
        }
      }
    }, parallel_);
  }

  // Step 2: the spatial Gaussian of every component, in the frequency domain, image by image. Two
  // real images share one complex transform; when their filters differ the spectrum is split into
  // the two images' (Hermitian) halves by Z(f) and conj Z(-f).
  void filter_space(size_t lights) {
    const size_t nv = views_.size(), groups = lights * nv * 2;
    const ParallelOptions options{.threads = parallel_.threads, .grain = 1};
    const size_t slots = parallel_slots(groups, options);
    std::vector<std::vector<std::complex<float>>> a(slots), b(slots);
    parallel_for(0, groups, [&](size_t first, size_t last, size_t slot) {
      auto& img = a[slot];
      auto& spec = b[slot];
      img.resize(texels_);
      spec.resize(texels_);
      for (size_t g = first; g < last; ++g) {
        const size_t lb = g / (nv * 2), v = (g / 2) % nv, s = g % 2;
        for (const auto& [re, im] : kPacking) {
          float* x = image(lb, v, s, size_t(re));
          float* y = im >= 0 ? image(lb, v, s, size_t(im)) : nullptr;
          for (size_t t = 0; t < texels_; ++t) img[t] = {x[t], y ? y[t] : 0.0f};
          fft_.forward(img.data(), spec.data());
          const float* ha = spatial(size_t(kChannels[size_t(re)].component), v);
          const float* hb = y ? spatial(size_t(kChannels[size_t(im)].component), v) : ha;
          if (ha == hb) {
            for (size_t j = 0; j < texels_; ++j) spec[j] *= ha[j];
          } else {
            split_filter(spec.data(), ha, hb);
          }
          fft_.inverse(spec.data(), img.data());
          for (size_t t = 0; t < texels_; ++t) x[t] = img[t].real();
          if (y)
            for (size_t t = 0; t < texels_; ++t) y[t] = img[t].imag();
        }
      }
    }, options);
  }

  // Z = A + i B with A, B the spectra of two real images: Y = Ha A + i Hb B
  //   = Z (Ha + Hb) / 2 + conj Z(-f) (Ha - Hb) / 2.
  void split_filter(std::complex<float>* z, const float* ha, const float* hb) const {
    for (size_t kx = 0; kx < width_; ++kx) {
      const size_t mx = (width_ - kx) % width_;
      for (size_t ky = 0; ky < height_; ++ky) {
        const size_t my = (height_ - ky) % height_;
        const size_t j = kx * height_ + ky, m = mx * height_ + my;
        if (m < j) continue;
        const std::complex<float> zj = z[j], zm = z[m];
        z[j] = zj * (0.5f * (ha[j] + hb[j])) + std::conj(zm) * (0.5f * (ha[j] - hb[j]));
        if (m != j) z[m] = zm * (0.5f * (ha[m] + hb[m])) + std::conj(zj) * (0.5f * (ha[m] - hb[m]));
      }
    }
  }

  // Step 3: the view-direction convolution of each component, the weighted sum of the components,
  // CIELab and CIEDE2000 for every pair (view, light in [l0, l1)).
  void compare(size_t l0, size_t l1) {
    const size_t nv = views_.size(), nl = lights_.size(), tasks = (l1 - l0) * nv;
    const ParallelOptions options{.threads = parallel_.threads, .grain = 1};
    const size_t slots = parallel_slots(tasks, options);
    std::vector<std::vector<float>> scratch(slots);
    parallel_for(0, tasks, [&](size_t first, size_t last, size_t slot) {
      auto& acc = scratch[slot];
      acc.resize(6 * texels_);
      for (size_t task = first; task < last; ++task) {
        const size_t lb = task / nv, v = task % nv;
        std::fill(acc.begin(), acc.end(), 0.0f);
        for (size_t s = 0; s < 2; ++s)
          for (size_t c = 0; c < kChannels.size(); ++c) {
            const size_t k = size_t(kChannels[c].component);
            float* out = acc.data() + (s * 3 + size_t(kChannels[c].channel)) * texels_;
            for (const auto& [w, g] : view_kernel_[k].rows[v]) {
              const float coef = float(kComponents[k].weight) * g;
              const float* in = image(lb, w, s, c);
              for (size_t t = 0; t < texels_; ++t) out[t] += coef * in[t];
            }
          }
        Partial p;
        for (size_t t = 0; t < texels_; ++t) {
          const CieLab x = colour_.to_lab(acc[t], acc[texels_ + t], acc[2 * texels_ + t]);
          const CieLab y = colour_.to_lab(acc[3 * texels_ + t], acc[4 * texels_ + t], acc[5 * texels_ + t]);
          const double de = ciede2000(x, y);
          p.sum += de;
          p.sum_sq += de * de;
        }
        partial_[v * nl + l0 + lb] = p;
      }
    }, options);
  }

  const MeasuredSample* samples_[2];
  BtfCielabOptions opt_;
  size_t width_, height_, texels_;
  std::vector<Direction> views_, lights_;
  Fft2d fft_;
  ParallelOptions parallel_;
  ColourModel colour_;
  std::vector<AngularKernel> view_kernel_, light_kernel_;  // per component
  std::vector<float> spatial_;                             // per component and view
  std::vector<float> filtered_;
  std::vector<Partial> partial_;
};

}  // namespace

BtfCielabReport btf_cielab(const MeasuredSample& reference, const MeasuredSample& test, const BtfCielabOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  check_geometry(reference, test);
  BtfCielabReport rep = BtfCielab(reference, test, options).run();
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return rep;
}

}  // namespace btfvq
