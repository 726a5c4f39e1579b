#include "pipeline/metrics/metrics.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>

#include <btfvq/error.h>
#include "pipeline/util/parallel.h"

namespace btfvq {

namespace {

// Normalised 1-D Gaussian of n taps centred on the window (the 2-D window of fspecial('gaussian')
// is the outer product of two of these).
std::vector<double> gaussian_weights(int n, double sigma) {
  std::vector<double> w(static_cast<size_t>(n));
  double sum = 0;
  for (int i = 0; i < n; ++i) {
    const double d = i - (n - 1) / 2.0;
    w[size_t(i)] = std::exp(-0.5 * d * d / (sigma * sigma));
    sum += w[size_t(i)];
  }
  for (double& v : w) v /= sum;
  return w;
}

// Two doubles processed together (GCC/Clang vector extension, plain SSE2 without -march), four
// outputs per step, because every image of a BTF goes through this loop.
using Double2 = double __attribute__((vector_size(16)));

Double2 load2(const double* p) {
  Double2 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
void store2(double* p, Double2 v) { std::memcpy(p, &v, sizeof v); }

// out[i] = sum_k g[k] * in[i + k * stride] for i in 0 .. n-1: one axis of the separable Gaussian
// window ('valid' part only).
void filter(const double* in, size_t stride, const std::vector<double>& g, double* out, int n) {
  int i = 0;
  for (; i + 4 <= n; i += 4) {
    Double2 lo = {0, 0}, hi = {0, 0};
    for (size_t k = 0; k < g.size(); ++k) {
      const double* p = in + i + k * stride;
      lo += g[k] * load2(p);
      hi += g[k] * load2(p + 2);
    }
    store2(out + i, lo);
    store2(out + i + 2, hi);
  }
  for (; i < n; ++i) {
    double acc = 0;
    for (size_t k = 0; k < g.size(); ++k) acc += g[k] * in[size_t(i) + k * stride];
    out[i] = acc;
  }
}

// Reusable buffers for the separable window sums, so evaluating thousands of images does not
// allocate per image.
class SsimWorkspace {
 public:
  explicit SsimWorkspace(const SsimParameters& p) : p_(p) {}

  // Calls `visit(ox, oy, ssim)` for every valid window position.
  template <class Visit>
  void run(const GrayImage& a, const GrayImage& b, Visit&& visit) {
    check(a, b);
    const int W = a.width, H = a.height;
    const int wx = std::min(p_.window, W), wy = std::min(p_.window, H);
    const int ow = W - wx + 1, oh = H - wy + 1;
    if (size_t(wx) != gx_.size() || size_t(wy) != gy_.size()) {
      gx_ = gaussian_weights(wx, p_.sigma);
      gy_ = gaussian_weights(wy, p_.sigma);
    }
    horizontal_pass(a, b, ow);
    const double c1 = sq(p_.k1 * p_.dynamic_range), c2 = sq(p_.k2 * p_.dynamic_range);
    for (auto& r : v_) r.resize(size_t(ow));
    for (int oy = 0; oy < oh; ++oy) {
      for (size_t k = 0; k < 5; ++k) filter(&h_[k][size_t(oy) * size_t(ow)], size_t(ow), gy_, v_[k].data(), ow);
      for (int ox = 0; ox < ow; ++ox) {
        const size_t i = size_t(ox);
        const double mx = v_[0][i], my = v_[1][i];
        const double vx = v_[2][i] - mx * mx, vy = v_[3][i] - my * my, cxy = v_[4][i] - mx * my;
        visit(ox, oy, ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2)));
      }
    }
  }

 private:
  static double sq(double x) { return x * x; }

  static void check(const GrayImage& a, const GrayImage& b) {
    if (a.width != b.width || a.height != b.height)
      throw InputError("SSIM: image sizes differ (" + std::to_string(a.width) + "x" + std::to_string(a.height) +
                       " vs " + std::to_string(b.width) + "x" + std::to_string(b.height) + ")");
    if (a.width <= 0 || a.height <= 0) throw InputError("SSIM: image is empty");
    if (a.pixels.size() != size_t(a.width) * size_t(a.height) || b.pixels.size() != a.pixels.size())
      throw InputError("SSIM: pixel count does not match the image size");
  }

  // Horizontal window sums of x, y, x^2, y^2, xy for every row and valid column.
  void horizontal_pass(const GrayImage& a, const GrayImage& b, int ow) {
    const int W = a.width, H = a.height;
    for (auto& r : h_) r.resize(size_t(H) * size_t(ow));
    for (auto& r : row_) r.resize(size_t(W));
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        const double s = a.at(x, y), t = b.at(x, y);
        row_[0][size_t(x)] = s;
        row_[1][size_t(x)] = t;
        row_[2][size_t(x)] = s * s;
        row_[3][size_t(x)] = t * t;
        row_[4][size_t(x)] = s * t;
      }
      for (size_t k = 0; k < 5; ++k) filter(row_[k].data(), 1, gx_, &h_[k][size_t(y) * size_t(ow)], ow);
    }
  }

  SsimParameters p_;
  std::vector<double> gx_, gy_;
  std::array<std::vector<double>, 5> row_, h_, v_;
};

double mean_ssim(SsimWorkspace& ws, const GrayImage& a, const GrayImage& b) {
  double sum = 0;
  size_t n = 0;
  ws.run(a, b, [&](int, int, double s) {
    sum += s;
    ++n;
  });
  return sum / double(n);
}

// sRGB transfer curve (IEC 61966-2-1) on 0..1.
double srgb_to_linear(double c) { return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4); }

// The same curve for every 8-bit code, for the integer values of LDR samples.
const std::array<double, 256>& srgb_table() {
  static const std::array<double, 256> t = [] {
    std::array<double, 256> r{};
    for (int i = 0; i < 256; ++i) r[size_t(i)] = srgb_to_linear(i / 255.0);
    return r;
  }();
  return t;
}

// Cube root of t > 0 to full double precision: Kahan's bit-level first guess (within 4 %) and three
// Halley steps (each cubes the relative error). libm's cbrt was a fifth of evaluate()'s time.
double cube_root(double t) {
  uint64_t bits;
  std::memcpy(&bits, &t, sizeof bits);
  bits = bits / 3 + 0x2A9F7893782DA1CEull;
  double y;
  std::memcpy(&y, &bits, sizeof y);
  for (int i = 0; i < 3; ++i) {
    const double y3 = y * y * y;
    y *= (y3 + 2 * t) / (2 * y3 + t);
  }
  return y;
}

double lab_f(double t) {
  constexpr double d = 6.0 / 29.0;
  return t > d * d * d ? cube_root(t) : t / (3 * d * d) + 4.0 / 29.0;
}

CieLab lab_of_xyz(double X, double Y, double Z) {
  constexpr double xn = 0.95047, yn = 1.0, zn = 1.08883;
  const double fx = lab_f(X / xn), fy = lab_f(Y / yn), fz = lab_f(Z / zn);
  return {116 * fy - 16, 500 * (fx - fy), 200 * (fy - fz)};
}

CieLab linear_to_lab(double r, double g, double b) {
  // Rec. 709 primaries, D65 white (Lindbloom's sRGB matrix; rows sum to the white point).
  const double* m = kSrgbToXyz;
  return lab_of_xyz(m[0] * r + m[1] * g + m[2] * b, m[3] * r + m[4] * g + m[5] * b, m[6] * r + m[7] * g + m[8] * b);
}

double linear_channel(float v) {
  const float c = std::clamp(v, 0.0f, 255.0f);
  const float r = std::nearbyint(c);
  if (r == c) return srgb_table()[size_t(r)];
  return srgb_to_linear(double(c) / 255.0);
}

constexpr double degrees(double rad) { return rad * 180.0 / 3.14159265358979323846; }
constexpr double radians(double deg) { return deg * 3.14159265358979323846 / 180.0; }

// Hue angle in degrees in [0, 360); 0 for the achromatic point, as Sharma et al. specify.
double hue(double b, double a) {
  if (a == 0 && b == 0) return 0;
  const double h = degrees(std::atan2(b, a));
  return h < 0 ? h + 360 : h;
}

double pow7(double x) {
  const double x2 = x * x;
  return x2 * x2 * x2 * x;
}

// T = 1 - 0.17 cos(h - 30) + 0.24 cos(2h) + 0.32 cos(3h + 6) - 0.20 cos(4h - 63) (angles in degrees),
// expanded by the angle-sum identities from one cos/sin pair: it is evaluated for every texel.
double hue_weight(double h) {
  const double c1 = std::cos(h), s1 = std::sin(h);
  const double c2 = 2 * c1 * c1 - 1, s2 = 2 * s1 * c1;
  const double c3 = c2 * c1 - s2 * s1, s3 = s2 * c1 + c2 * s1;
  const double c4 = 2 * c2 * c2 - 1, s4 = 2 * s2 * c2;
  // cos(h + d) = cos h cos d - sin h sin d for the fixed offsets d = -30, 6, -63 degrees.
  const double k30c = std::cos(radians(-30)), k30s = std::sin(radians(-30));
  const double k6c = std::cos(radians(6)), k6s = std::sin(radians(6));
  const double k63c = std::cos(radians(-63)), k63s = std::sin(radians(-63));
  return 1 - 0.17 * (c1 * k30c - s1 * k30s) + 0.24 * c2 + 0.32 * (c3 * k6c - s3 * k6s) - 0.20 * (c4 * k63c - s4 * k63s);
}

}  // namespace

GrayImage ssim_map(const GrayImage& a, const GrayImage& b, const SsimParameters& p) {
  SsimWorkspace ws(p);
  GrayImage out(std::max(1, a.width - std::min(p.window, a.width) + 1),
                std::max(1, a.height - std::min(p.window, a.height) + 1));
  ws.run(a, b, [&](int ox, int oy, double s) { out.at(ox, oy) = float(s); });
  return out;
}

double mssim(const GrayImage& a, const GrayImage& b, const SsimParameters& p) {
  SsimWorkspace ws(p);
  return mean_ssim(ws, a, b);
}

double psnr_from_mse(double mse) {
  if (mse <= 0) return std::numeric_limits<double>::infinity();
  return 10.0 * std::log10(255.0 * 255.0 / mse);
}

double psnr(std::span<const uint8_t> a, std::span<const uint8_t> b) {
  if (a.size() != b.size())
    throw InputError("PSNR: value counts differ (" + std::to_string(a.size()) + " vs " + std::to_string(b.size()) + ")");
  if (a.empty()) throw InputError("PSNR: no values");
  uint64_t sse = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const int d = int(a[i]) - int(b[i]);
    sse += uint64_t(d * d);
  }
  return psnr_from_mse(double(sse) / double(a.size()));
}

double srgb8_to_linear(float v) { return linear_channel(v); }
CieLab xyz_to_lab(double x, double y, double z) { return lab_of_xyz(x, y, z); }

CieLab srgb_to_lab(const Rgb& c) { return linear_to_lab(linear_channel(c.r), linear_channel(c.g), linear_channel(c.b)); }

double ciede2000(const CieLab& x, const CieLab& y) {
  constexpr double k25_7 = 6103515625.0;  // 25^7
  const double c1 = std::sqrt(x.a * x.a + x.b * x.b), c2 = std::sqrt(y.a * y.a + y.b * y.b);
  const double cbar7 = pow7((c1 + c2) / 2);
  const double g = 0.5 * (1 - std::sqrt(cbar7 / (cbar7 + k25_7)));
  const double a1 = (1 + g) * x.a, a2 = (1 + g) * y.a;
  const double cp1 = std::sqrt(a1 * a1 + x.b * x.b), cp2 = std::sqrt(a2 * a2 + y.b * y.b);
  const double h1 = hue(x.b, a1), h2 = hue(y.b, a2);

  const double dl = y.l - x.l, dc = cp2 - cp1;
  double dh = 0;
  if (cp1 * cp2 != 0) {
    dh = h2 - h1;
    if (dh > 180) dh -= 360;
    if (dh < -180) dh += 360;
  }
  const double dH = 2 * std::sqrt(cp1 * cp2) * std::sin(radians(dh / 2));

  const double lbar = (x.l + y.l) / 2, cbar = (cp1 + cp2) / 2;
  double hbar = h1 + h2;
  if (cp1 * cp2 != 0) {
    if (std::abs(h1 - h2) <= 180)
      hbar = (h1 + h2) / 2;
    else
      hbar = (h1 + h2 < 360) ? (h1 + h2 + 360) / 2 : (h1 + h2 - 360) / 2;
  }
  const double t = hue_weight(radians(hbar));
  const double dtheta = 30 * std::exp(-((hbar - 275) / 25) * ((hbar - 275) / 25));
  const double cbar_7 = pow7(cbar);
  const double rc = 2 * std::sqrt(cbar_7 / (cbar_7 + k25_7));
  const double l50 = (lbar - 50) * (lbar - 50);
  const double sl = 1 + 0.015 * l50 / std::sqrt(20 + l50);
  const double sc = 1 + 0.045 * cbar, sh = 1 + 0.015 * cbar * t;
  const double rt = -std::sin(radians(2 * dtheta)) * rc;
  const double tl = dl / sl, tc = dc / sc, th = dH / sh;
  return std::sqrt(tl * tl + tc * tc + th * th + rt * tc * th);
}

float display_value(float v, Dynamic dynamic) {
  if (dynamic == Dynamic::LDR) return v;
  if (!(v > 0.0f)) return 0.0f;  // also NaN: a broken texel must not poison the histogram index
  return std::min(255.0f * std::pow(v, 1.0f / 2.2f), 255.0f);
}

namespace {

void check_same_geometry(const MeasuredSample& r, const MeasuredSample& t) {
  auto size = [](const MeasuredSample& s) { return std::to_string(s.width()) + "x" + std::to_string(s.height()); };
  if (r.width() != t.width() || r.height() != t.height())
    throw InputError("evaluate: spatial size differs (reference " + size(r) + ", test " + size(t) + ")");
  if (r.dynamic() != t.dynamic()) throw InputError("evaluate: one sample is LDR and the other HDR");
  if (r.views() != t.views()) throw InputError("evaluate: view directions differ");
  for (size_t v = 0; v < r.view_count(); ++v)
    if (r.lights(v) != t.lights(v)) throw InputError("evaluate: light directions of view " + std::to_string(v) + " differ");
  if (r.texel_count() == 0 || r.pair_count() == 0) throw InputError("evaluate: sample has no images");
}

constexpr size_t kHistogramBins = size_t(256 / kCiede2000Resolution);
constexpr size_t kPairsPerBatch = 16;  // 48 contiguous bytes per texel per LDR gather

// The images of one (view, light) pair in both samples, as display values.
struct PairImages {
  std::vector<Rgb> ref, test;
};

// Per-image results, summed in pair order at the end so the report does not depend on threads.
struct PairResult {
  double ssim_y = 0, ssim_cb = 0, ssim_cr = 0, sse = 0, de_sum = 0;
};

class Evaluator {
 public:
  Evaluator(const MeasuredSample& r, const MeasuredSample& t) : r_(r), t_(t), results_(r.pair_count()) {}

  EvaluationReport run(int threads) {
    const size_t pairs = r_.pair_count();
    const ParallelOptions options{.threads = size_t(std::max(1, threads)), .grain = kPairsPerBatch};
    std::vector<Scratch> scratch;
    const size_t slots = parallel_slots(pairs, options);
    scratch.reserve(slots);
    for (size_t i = 0; i < slots; ++i) scratch.emplace_back(r_.width(), r_.height());
    parallel_for(0, pairs, [&](size_t first, size_t last, size_t slot) { work(first, last, scratch[slot]); }, options);
    for (size_t i = 1; i < scratch.size(); ++i)
      for (size_t k = 0; k < kHistogramBins; ++k) scratch[0].hist[k] += scratch[i].hist[k];
    return report(scratch[0].hist);
  }

 private:
  // One worker's buffers, kept across its batches: a batch of images is 25 MB at 256 x 256.
  struct Scratch {
    Scratch(int width, int height) : ws{SsimParameters{}}, batch(kPairsPerBatch), hist(kHistogramBins, 0) {
      for (auto& p : planes) p = GrayImage(width, height);
    }
    SsimWorkspace ws;
    std::vector<PairImages> batch;
    GrayImage planes[6];
    std::vector<uint64_t> hist;
  };

  void work(size_t first, size_t last, Scratch& s) {
    const size_t count = last - first;
    gather(first, count, s.batch);
    for (size_t k = 0; k < count; ++k) results_[first + k] = compare(s.batch[k], s.ws, s.planes, s.hist);
  }

  // Texel-major storage: copy `count` consecutive pairs of every texel at once, so each texel's
  // values are read from one or two cache lines.
  void gather(size_t first, size_t count, std::vector<PairImages>& batch) const {
    const size_t texels = r_.texel_count();
    for (size_t k = 0; k < count; ++k) {
      batch[k].ref.resize(texels);
      batch[k].test.resize(texels);
    }
    const size_t pairs = r_.pair_count();
    for (size_t t = 0; t < texels; ++t) {
      const size_t base = (t * pairs + first) * 3;
      for (size_t k = 0; k < count; ++k) {
        batch[k].ref[t] = display(r_, base + 3 * k);
        batch[k].test[t] = display(t_, base + 3 * k);
      }
    }
  }

  // The display value of the colour stored at raw index i.
  static Rgb display(const MeasuredSample& s, size_t i) {
    if (!s.is_hdr()) {
      const uint8_t* v = s.ldr_data().data() + i;
      return {float(v[0]), float(v[1]), float(v[2])};
    }
    const float* v = s.hdr_data().data() + i;
    return {display_value(v[0], Dynamic::HDR), display_value(v[1], Dynamic::HDR), display_value(v[2], Dynamic::HDR)};
  }

  static PairResult compare(const PairImages& img, SsimWorkspace& ws, GrayImage* planes, std::vector<uint64_t>& hist) {
    PairResult out;
    for (size_t i = 0; i < img.ref.size(); ++i) {
      const Rgb a = img.ref[i], b = img.test[i];
      planes[0].pixels[i] = bt601_luma(a);
      planes[1].pixels[i] = bt601_luma(b);
      const YCbCr ya = rgb_to_ycbcr(a), yb = rgb_to_ycbcr(b);
      planes[2].pixels[i] = ya.cb;
      planes[3].pixels[i] = yb.cb;
      planes[4].pixels[i] = ya.cr;
      planes[5].pixels[i] = yb.cr;
      const double dr = double(a.r) - b.r, dg = double(a.g) - b.g, db = double(a.b) - b.b;
      out.sse += dr * dr + dg * dg + db * db;
      const double de = ciede2000(srgb_to_lab(a), srgb_to_lab(b));
      out.de_sum += de;
      hist[std::min(size_t(de / kCiede2000Resolution), kHistogramBins - 1)]++;
    }
    out.ssim_y = mean_ssim(ws, planes[0], planes[1]);
    out.ssim_cb = mean_ssim(ws, planes[2], planes[3]);
    out.ssim_cr = mean_ssim(ws, planes[4], planes[5]);
    return out;
  }

  EvaluationReport report(const std::vector<uint64_t>& hist) const {
    EvaluationReport rep;
    rep.images = results_.size();
    double sse = 0, de = 0;
    for (const auto& p : results_) {
      rep.mssim_y += p.ssim_y;
      rep.mssim_cb += p.ssim_cb;
      rep.mssim_cr += p.ssim_cr;
      sse += p.sse;
      de += p.de_sum;
    }
    const double n_img = double(rep.images), n_texels = n_img * double(r_.texel_count());
    rep.mssim_y /= n_img;
    rep.mssim_cb /= n_img;
    rep.mssim_cr /= n_img;
    rep.psnr = psnr_from_mse(sse / (3 * n_texels));
    rep.ciede2000_mean = de / n_texels;
    // Nearest rank: the smallest value with at least 95 % of all values at or below it.
    const uint64_t total = uint64_t(n_texels);
    const uint64_t rank = uint64_t(std::ceil(0.95 * double(total)));
    uint64_t seen = 0;
    for (size_t k = 0; k < hist.size(); ++k) {
      seen += hist[k];
      if (seen >= std::max<uint64_t>(rank, 1)) {
        rep.ciede2000_p95 = (double(k) + 0.5) * kCiede2000Resolution;
        break;
      }
    }
    return rep;
  }

  const MeasuredSample& r_;
  const MeasuredSample& t_;
  std::vector<PairResult> results_;
};

}  // namespace

EvaluationReport evaluate(const MeasuredSample& reference, const MeasuredSample& test, int threads) {
  check_same_geometry(reference, test);
  return Evaluator(reference, test).run(threads);
}

}  // namespace btfvq
