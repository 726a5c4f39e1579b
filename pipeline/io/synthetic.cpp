#include "pipeline/io/synthetic.h"

#include <algorithm>
#include <cmath>

#include <btfvq/directions.h>
#include <btfvq/error.h>
#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/util/parallel.h"

namespace btfvq {

// The C++ reference of kernels/synthetic.cl is the kernel text itself, compiled as C++: the prelude
// maps the few OpenCL spellings it uses onto their C++ equivalents.
namespace synth_cl {
using std::floor;
using std::fmax;
using std::fmin;
using std::sqrt;
using uchar = unsigned char;
inline float clamp(float v, float lo, float hi) { return fmin(fmax(v, lo), hi); }
#define __global
#define SYNTH_REFERENCE 1
#include "kernels/synthetic.cl"
#undef __global
#undef SYNTH_REFERENCE
}  // namespace synth_cl

namespace {

// ---------------------------------------------------------------------------------------------
// Deterministic randomness: splitmix64 for sequences, a hash of (seed, lattice point) for noise.

uint64_t mix64(uint64_t z) {
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

class Rng {
 public:
  explicit Rng(uint64_t seed) : state_(seed) {}
  uint64_t next() { return mix64(state_ += 0x9e3779b97f4a7c15ULL); }
  double uniform() { return double(next() >> 11) * (1.0 / 9007199254740992.0); }  // [0, 1)
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }

 private:
  uint64_t state_;
};

double lattice_value(uint64_t seed, int i, int j) {  // in [-1, 1)
  const uint64_t h = mix64(seed ^ mix64(uint64_t(uint32_t(i)) * 0x100000001b3ULL + uint64_t(uint32_t(j))));
  return double(h >> 11) * (2.0 / 9007199254740992.0) - 1.0;
}

double fade(double t) { return t * t * t * (t * (t * 6 - 15) + 10); }
int wrap(int i, int n) { return ((i % n) + n) % n; }

// Value noise that tiles a W x H texture: the lattice has a whole number of cells across each side.
class TileNoise {
 public:
  TileNoise(uint64_t seed, int width, int height, double cell_x, double cell_y)
      : seed_(seed),
        nx_(std::max(1, int(std::lround(width / cell_x)))),
        ny_(std::max(1, int(std::lround(height / cell_y)))),
        sx_(double(nx_) / width),
        sy_(double(ny_) / height) {}

  double operator()(double x, double y) const {
    const double u = x * sx_, v = y * sy_;
    const double fu = std::floor(u), fv = std::floor(v);
    const int i = int(fu), j = int(fv);
    const double a = fade(u - fu), b = fade(v - fv);
    auto at = [&](int di, int dj) { return lattice_value(seed_, wrap(i + di, nx_), wrap(j + dj, ny_)); };
    const double top = at(0, 0) + (at(1, 0) - at(0, 0)) * a;
    const double bottom = at(0, 1) + (at(1, 1) - at(0, 1)) * a;
    return top + (bottom - top) * b;
  }

 private:
  uint64_t seed_;
  int nx_, ny_;
  double sx_, sy_;
};

// Fractal sum of tileable octaves, roughly in [-1, 1].
class Fbm {
 public:
  Fbm(uint64_t seed, int width, int height, double cell_x, double cell_y, int octaves) {
    double amplitude = 1, total = 0;
    for (int o = 0; o < octaves; ++o) {
      octaves_.emplace_back(mix64(seed + uint64_t(o) * 7919), width, height, cell_x, cell_y);
      weights_.push_back(amplitude);
      total += amplitude;
      amplitude *= 0.5;
      cell_x = std::max(1.0, cell_x / 2);
      cell_y = std::max(1.0, cell_y / 2);
    }
    for (double& w : weights_) w /= total;
  }
  double operator()(double x, double y) const {
    double s = 0;
    for (size_t o = 0; o < octaves_.size(); ++o) s += weights_[o] * octaves_[o](x, y);
    return s;
  }

 private:
  std::vector<TileNoise> octaves_;
  std::vector<double> weights_;
};

// Distances to the nearest and second-nearest feature point of a tileable cellular pattern, in cell units.
class TileCells {
 public:
  TileCells(uint64_t seed, int width, int height, double cell)
      : seed_(seed),
        nx_(std::max(1, int(std::lround(width / cell)))),
        ny_(std::max(1, int(std::lround(height / cell)))),
        sx_(double(nx_) / width),
        sy_(double(ny_) / height) {}

  std::pair<double, double> operator()(double x, double y) const {
    const double u = x * sx_, v = y * sy_;
    const int i = int(std::floor(u)), j = int(std::floor(v));
    double f1 = 1e9, f2 = 1e9;
    for (int dj = -1; dj <= 1; ++dj)
      for (int di = -1; di <= 1; ++di) {
        const int ci = wrap(i + di, nx_), cj = wrap(j + dj, ny_);
        const double px = i + di + 0.5 + 0.45 * lattice_value(seed_, ci, cj);
        const double py = j + dj + 0.5 + 0.45 * lattice_value(seed_ ^ 0x5bd1e995ULL, ci, cj);
        const double d = std::hypot(px - u, py - v);
        if (d < f1) {
          f2 = f1;
          f1 = d;
        } else if (d < f2) {
          f2 = d;
        }
      }
    return {f1, f2};
  }

 private:
  uint64_t seed_;
  int nx_, ny_;
  double sx_, sy_;
};

double smoothstep(double a, double b, double x) {
  const double t = std::clamp((x - a) / (b - a), 0.0, 1.0);
  return t * t * (3 - 2 * t);
}
double fract(double x) { return x - std::floor(x); }

// ---------------------------------------------------------------------------------------------
// Presets: each fills the fields of every texel; normals come from the height field afterwards.

struct Fields {
  int w = 0, h = 0;
  std::vector<double> height, albedo, f0, alpha_t, alpha_b, angle, tilt_x, tilt_y;
  explicit Fields(int size)
      : w(size),
        h(size),
        height(size_t(size) * size, 0),
        albedo(size_t(size) * size * 3, 0),
        f0(size_t(size) * size * 3, 0.04),
        alpha_t(size_t(size) * size, 0.3),
        alpha_b(size_t(size) * size, 0.3),
        angle(size_t(size) * size, 0),
        tilt_x(size_t(size) * size, 0),
        tilt_y(size_t(size) * size, 0) {}
  size_t at(int x, int y) const { return size_t(y) * w + x; }
  void set_albedo(size_t i, double r, double g, double b) {
    albedo[3 * i] = r;
    albedo[3 * i + 1] = g;
    albedo[3 * i + 2] = b;
  }
  void set_f0(size_t i, double r, double g, double b) {
    f0[3 * i] = r;
    f0[3 * i + 1] = g;
    f0[3 * i + 2] = b;
  }
  template <class F>
  void each(F&& f) {
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) f(x, y, at(x, y));
  }
};

// Glazed ceramic: nearly flat, nearly uniform pale glaze, glossy.
void make_tile(Fields& m, uint64_t seed) {
  const Fbm wave(seed, m.w, m.h, 32, 32, 2), tint(seed + 1, m.w, m.h, 16, 16, 3);
  m.each([&](int x, int y, size_t i) {
    m.height[i] = 0.1 * (wave(x, y) + 1);
    const double t = 1 + 0.03 * tint(x, y);
    m.set_albedo(i, 0.30 * t, 0.34 * t, 0.38 * t);
    m.alpha_t[i] = m.alpha_b[i] = 0.2;
  });
}

// Metal foil: slightly crinkled mirror-like metal with sparse tilted flakes that sparkle.
void make_foil(Fields& m, uint64_t seed) {
  const Fbm crinkle(seed, m.w, m.h, 24, 24, 3);
  m.each([&](int x, int y, size_t i) {
    m.height[i] = 0.15 * (crinkle(x, y) + 1);
    m.set_albedo(i, 0.01, 0.01, 0.01);
    m.set_f0(i, 0.91, 0.92, 0.92);
    m.alpha_t[i] = m.alpha_b[i] = 0.22;
  });
  const double cell = 6;
  const int nx = std::max(1, int(std::lround(m.w / cell))), ny = std::max(1, int(std::lround(m.h / cell)));
  Rng rng(mix64(seed ^ 0xf1a4e5ULL));
  for (int cj = 0; cj < ny; ++cj)
    for (int ci = 0; ci < nx; ++ci) {
      const double has = rng.uniform(), cx = (ci + rng.uniform(0.3, 0.7)) * m.w / nx,
                   cy = (cj + rng.uniform(0.3, 0.7)) * m.h / ny, radius = rng.uniform(1.0, 2.2),
                   tilt = std::tan(rng.uniform(8, 32) * kDeg), azimuth = rng.uniform(0, 2 * kPi);
      if (has > 0.15) continue;
      for (int y = int(cy - radius) - 1; y <= int(cy + radius) + 1; ++y)
        for (int x = int(cx - radius) - 1; x <= int(cx + radius) + 1; ++x) {
          if (std::hypot(x - cx, y - cy) > radius) continue;
          const size_t i = m.at(wrap(x, m.w), wrap(y, m.h));
          m.tilt_x[i] = tilt * std::cos(azimuth);
          m.tilt_y[i] = tilt * std::sin(azimuth);
          m.alpha_t[i] = m.alpha_b[i] = 0.06;
          m.set_f0(i, 0.95, 0.95, 0.96);
        }
    }
}

// Wood: growth rings and streaks along the grain, shallow grooves, anisotropic varnish highlights.
void make_wood(Fields& m, uint64_t seed) {
  const Fbm warp(seed, m.w, m.h, 48, 48, 3), ring_jitter(seed + 1, m.w, m.h, 64, 64, 2);
  const Fbm streak(seed + 2, m.w, m.h, 24, 1.5, 3), pores(seed + 3, m.w, m.h, 6, 1, 2);
  const double period = std::max(1.0, double(m.h) / std::max(1L, std::lround(m.h / 9.0)));
  auto grain = [&](double x, double y) { return y + 5 * warp(x, y); };
  m.each([&](int x, int y, size_t i) {
    const double ring = fract(grain(x, y) / period + 0.25 * ring_jitter(x, y));
    const double late = smoothstep(0.55, 0.9, ring) * (1 - smoothstep(0.95, 1.0, ring));
    const double s = 0.85 + 0.15 * streak(x, y);
    m.set_albedo(i, (0.55 - 0.27 * late) * s, (0.35 - 0.2 * late) * s, (0.17 - 0.11 * late) * s);
    m.height[i] = 0.45 * (1 - late) + 0.12 * (streak(x, y) + 1) + 0.1 * std::max(0.0, -pores(x, y));
    const double gx = grain(x + 0.5, y) - grain(x - 0.5, y), gy = grain(x, y + 0.5) - grain(x, y - 0.5);
    m.angle[i] = std::atan2(-gx, gy);  // along the iso-lines of the grain coordinate
    m.alpha_t[i] = 0.08;
    m.alpha_b[i] = 0.35;
    m.set_f0(i, 0.045, 0.045, 0.045);
  });
}

// Leather: rounded cells separated by creases, fine pores, a semi-matt finish.
void make_leather(Fields& m, uint64_t seed) {
  const TileCells cells(seed, m.w, m.h, 7);
  const Fbm fine(seed + 1, m.w, m.h, 3, 3, 2), tone(seed + 2, m.w, m.h, 20, 20, 3);
  m.each([&](int x, int y, size_t i) {
    const auto [f1, f2] = cells(x, y);
    const double plateau = 1 - std::exp(-4 * (f2 - f1));
    m.height[i] = 1.3 * plateau + 0.12 * (fine(x, y) + 1);
    const double t = (0.8 + 0.25 * tone(x, y)) * (0.55 + 0.45 * plateau);
    m.set_albedo(i, 0.32 * t, 0.17 * t, 0.08 * t);
    m.alpha_t[i] = m.alpha_b[i] = 0.35 + 0.1 * fine(x, y);
  });
}

// Plain-weave fabric: warp threads along y, weft along x, alternately over and under.
void make_fabric(Fields& m, uint64_t seed) {
  const double pitch_x = double(m.w) / std::max(1L, std::lround(m.w / 8.0));
  const double pitch_y = double(m.h) / std::max(1L, std::lround(m.h / 8.0));
  const Fbm fibre_warp(seed, m.w, m.h, 1.5, 12, 2), fibre_weft(seed + 1, m.w, m.h, 12, 1.5, 2);
  const double lift = 0.6, radius = 1.3;
  auto profile = [](double f) { return std::sqrt(std::max(0.0, 1 - std::pow((f - 0.5) / 0.44, 2))); };
  m.each([&](int x, int y, size_t i) {
    const double u = x / pitch_x, v = y / pitch_y;
    const int ci = int(std::floor(u)), cj = int(std::floor(v));
    const double a_warp = profile(u - ci), a_weft = profile(v - cj);
    const double z_warp = lift * std::cos(kPi * (v - 0.5) + kPi * ci);
    const double z_weft = -lift * std::cos(kPi * (u - 0.5) + kPi * cj);
    const double h_warp = a_warp > 0 ? lift + z_warp + radius * a_warp : 0;
    const double h_weft = a_weft > 0 ? lift + z_weft + radius * a_weft : 0;
    const bool warp_on_top = h_warp >= h_weft;
    m.height[i] = std::max(h_warp, h_weft);
    if (warp_on_top) {
      const double s = 0.8 + 0.2 * fibre_warp(x, y);
      m.set_albedo(i, 0.55 * s, 0.12 * s, 0.10 * s);
      m.angle[i] = kPi / 2;
    } else {
      const double s = 0.8 + 0.2 * fibre_weft(x, y);
      m.set_albedo(i, 0.72 * s, 0.66 * s, 0.50 * s);
      m.angle[i] = 0;
    }
    m.alpha_t[i] = 0.25;
    m.alpha_b[i] = 0.6;
  });
}

// Corduroy: tall pile ribs along y with deep grooves, velvety and rough.
void make_corduroy(Fields& m, uint64_t seed) {
  const double pitch = double(m.w) / std::max(1L, std::lround(m.w / 7.0));
  const Fbm pile(seed, m.w, m.h, 2, 2, 2), tone(seed + 1, m.w, m.h, 16, 40, 2);
  m.each([&](int x, int y, size_t i) {
    const double f = fract(x / pitch);
    const double a = std::sqrt(std::max(0.0, 1 - std::pow((f - 0.5) / 0.46, 2)));
    m.height[i] = 2.4 * std::pow(a, 0.7) + 0.25 * (pile(x, y) + 1);
    const double t = (0.85 + 0.15 * tone(x, y)) * (0.5 + 0.5 * a);
    m.set_albedo(i, 0.30 * t, 0.26 * t, 0.12 * t);
    m.angle[i] = kPi / 2;
    m.alpha_t[i] = 0.4;
    m.alpha_b[i] = 0.8;
  });
}

// Wool: a felt of curved fibres piled on each other, deep gaps, strong shadowing.
void make_wool(Fields& m, uint64_t seed) {
  const Fbm felt(seed, m.w, m.h, 8, 8, 3);
  m.each([&](int x, int y, size_t i) {
    m.height[i] = 0.3 * (felt(x, y) + 1);
    const double t = 0.55 + 0.1 * felt(x, y);
    m.set_albedo(i, 0.70 * t, 0.64 * t, 0.52 * t);
    m.alpha_t[i] = 0.35;
    m.alpha_b[i] = 0.75;
  });
  Rng rng(mix64(seed ^ 0x3001ULL));
  const size_t fibres = std::max<size_t>(1, size_t(m.w) * m.h / 10);
  for (size_t f = 0; f < fibres; ++f) {
    double cx = rng.uniform(0, m.w), cy = rng.uniform(0, m.h), heading = rng.uniform(0, 2 * kPi);
    const double bend = rng.uniform(-0.08, 0.08), length = rng.uniform(8, 30), r = rng.uniform(0.7, 1.4);
    const double base = rng.uniform(0.2, 2.6), shade = rng.uniform(0.75, 1.05);
    for (double walked = 0; walked < length; walked += 0.5) {
      const double z = base + 0.6 * std::sin(kPi * walked / length);  // fibres arch over the felt
      for (int y = int(std::floor(cy - r)); y <= int(std::ceil(cy + r)); ++y)
        for (int x = int(std::floor(cx - r)); x <= int(std::ceil(cx + r)); ++x) {
          const double d = std::hypot(x - cx, y - cy);
          if (d >= r) continue;
          const double top = z + r * std::sqrt(1 - (d / r) * (d / r));
          const size_t i = m.at(wrap(x, m.w), wrap(y, m.h));
          if (top <= m.height[i]) continue;
          m.height[i] = top;
          m.angle[i] = heading;
          m.set_albedo(i, 0.80 * shade, 0.74 * shade, 0.60 * shade);
          m.alpha_t[i] = 0.3;
          m.alpha_b[i] = 0.7;
        }
      cx += 0.5 * std::cos(heading);
      cy += 0.5 * std::sin(heading);
      heading += 0.5 * bend;
    }
  }
}

struct PresetDef {
  SyntheticPreset info;
  void (*make)(Fields&, uint64_t);
  float exposure;
};

const std::vector<PresetDef>& preset_defs() {
  static const std::vector<PresetDef> defs = {
      {{"tile", "glazed ceramic tile: flat, almost uniform, glossy (easiest)"}, make_tile, 1.6f},
      {{"foil", "metal foil: crinkled mirror-like metal with sparse sparkling tilted flakes"}, make_foil, 0.35f},
      {{"wood", "varnished wood: growth rings and streaks, shallow grooves, anisotropic highlights"}, make_wood, 1.6f},
      {{"leather", "leather: rounded bumps between creases, fine pores, semi-matt"}, make_leather, 2.0f},
      {{"fabric", "plain-weave fabric: over/under threads in two colours, parallax and shadows"}, make_fabric, 1.6f},
      {{"corduroy", "corduroy: tall rough pile ribs with deep grooves"}, make_corduroy, 2.0f},
      {{"wool", "wool: piled curved fibres, strong height variation and shadowing (hardest)"}, make_wool, 2.2f},
  };
  return defs;
}

const PresetDef& find_preset(const std::string& name) {
  std::string names;
  for (const auto& d : preset_defs()) {
    if (d.info.name == name) return d;
    names += (names.empty() ? "" : ", ") + d.info.name;
  }
  throw InputError("unknown synthetic preset '" + name + "' (presets: " + names + ")");
}

MaterialMaps pack(const Fields& m, float exposure) {
  MaterialMaps out;
  out.width = m.w;
  out.height = m.h;
  out.exposure = exposure;
  out.texels.assign(size_t(m.w) * m.h * kMaterialStride, 0.0f);
  double top = 0;
  for (int y = 0; y < m.h; ++y)
    for (int x = 0; x < m.w; ++x) {
      const size_t i = m.at(x, y);
      float* r = &out.texels[i * kMaterialStride];
      // Central differences on the wrapped height field give the macro normal; flakes tilt it.
      const double gx = (m.height[m.at(wrap(x + 1, m.w), y)] - m.height[m.at(wrap(x - 1, m.w), y)]) / 2;
      const double gy = (m.height[m.at(x, wrap(y + 1, m.h))] - m.height[m.at(x, wrap(y - 1, m.h))]) / 2;
      const double nx = -gx + m.tilt_x[i], ny = -gy + m.tilt_y[i];
      const double len = std::sqrt(nx * nx + ny * ny + 1);
      r[0] = float(m.height[i]);
      r[1] = float(nx / len);
      r[2] = float(ny / len);
      r[3] = float(1 / len);
      for (int c = 0; c < 3; ++c) {
        r[4 + c] = float(m.albedo[3 * i + c]);
        r[7 + c] = float(m.f0[3 * i + c]);
      }
      r[10] = float(m.alpha_t[i]);
      r[11] = float(m.alpha_b[i]);
      r[12] = float(std::cos(m.angle[i]));
      r[13] = float(std::sin(m.angle[i]));
      top = std::max(top, m.height[i]);
    }
  out.height_max = float(top) + 0.01f;
  return out;
}

// ---------------------------------------------------------------------------------------------
// Rendering.

std::vector<float> direction_vectors() {
  std::vector<float> v;
  for (const auto& d : bonn81()) {
    const Vec3 u = to_vector(d);
    v.insert(v.end(), {float(u.x), float(u.y), float(u.z)});
  }
  return v;
}

const std::vector<uint8_t>& srgb_table() {
  static const std::vector<uint8_t> lut = [] {
    std::vector<uint8_t> t(SYNTH_SRGB_LUT);
    for (size_t i = 0; i < t.size(); ++i) {
      const double x = double(i) / double(t.size() - 1);
      const double s = x <= 0.0031308 ? 12.92 * x : 1.055 * std::pow(x, 1 / 2.4) - 0.055;
      t[i] = uint8_t(std::lround(255 * s));
    }
    return t;
  }();
  return lut;
}

// The reference renderer is the slow path (tests, machines without OpenCL), so it takes every core;
// 16 at most, the cap it has always had.
const ParallelOptions kRenderThreads{.threads = 16};

void render_reference(const MaterialMaps& maps, MeasuredSample& out, const ProgressFn& progress) {
  const auto dirs = direction_vectors();
  const int n_dirs = int(bonn81().size());
  const int texels = maps.width * maps.height;
  std::vector<float> shadows(size_t(texels) * n_dirs);
  parallel_for(0, shadows.size(), [&](size_t i) {
    const int l = int(i / texels), t = int(i % texels);
    shadows[i] = synth_cl::synth_shadow(maps.texels.data(), maps.width, maps.height, maps.height_max, t,
                                        synth_cl::synth_vec(dirs[3 * l], dirs[3 * l + 1], dirs[3 * l + 2]));
  }, kRenderThreads);
  const int hdr = out.is_hdr() ? 1 : 0;
  parallel_for(0, size_t(texels), [&](size_t t) {
    for (int v = 0; v < n_dirs; ++v)
      synth_cl::synth_shade_item(maps.texels.data(), shadows.data(), dirs.data(), dirs.data(), srgb_table().data(),
                                 maps.width, maps.height, maps.height_max, maps.exposure, n_dirs, n_dirs, 0, int(t), v,
                                 hdr, out.ldr_data().data(), out.hdr_data().data());
  }, kRenderThreads);
  if (progress) progress(size_t(texels), size_t(texels));
}

void render_opencl(const MaterialMaps& maps, MeasuredSample& out, const ProgressFn& progress) {
  auto& dev = ComputeDevice::get();
  if (!dev.uses_opencl()) throw DeviceError("the OpenCL render path was requested but " + dev.description());
  const auto dirs = direction_vectors();
  const int n_dirs = int(bonn81().size());
  const int texels = maps.width * maps.height;
  const size_t pair_count = size_t(n_dirs) * n_dirs;
  const size_t value_bytes = out.is_hdr() ? sizeof(float) : 1;
  opencl_call("synthetic render", [&] {
    auto b_maps = dev.upload(maps.texels), b_dirs = dev.upload(dirs), b_lut = dev.upload(srgb_table());
    auto b_shadows = dev.allocate(size_t(texels) * n_dirs * sizeof(float));
    auto shadow_kernel = dev.kernel("synthetic.cl", "synth_shadow_map");
    int arg = 0;
    shadow_kernel.setArg(arg++, b_maps);
    shadow_kernel.setArg(arg++, b_dirs);
    shadow_kernel.setArg(arg++, cl_int(maps.width));
    shadow_kernel.setArg(arg++, cl_int(maps.height));
    shadow_kernel.setArg(arg++, cl_float(maps.height_max));
    shadow_kernel.setArg(arg++, cl_int(n_dirs));
    shadow_kernel.setArg(arg++, b_shadows);
    dev.queue().enqueueNDRangeKernel(shadow_kernel, cl::NullRange,
                                     cl::NDRange(round_up(size_t(texels) * n_dirs, 64)));

    // Shade in chunks of texels so the device buffer stays small whatever the sample size.
    const int chunk = int(std::max<size_t>(1, (size_t(64) << 20) / (pair_count * 3 * value_bytes)));
    auto b_out = dev.allocate(size_t(std::min(chunk, texels)) * pair_count * 3 * value_bytes, CL_MEM_WRITE_ONLY);
    auto b_unused = dev.allocate(sizeof(float), CL_MEM_WRITE_ONLY);
    auto shade = dev.kernel("synthetic.cl", "synth_shade");
    for (int first = 0; first < texels; first += chunk) {
      const int count = std::min(chunk, texels - first);
      arg = 0;
      shade.setArg(arg++, b_maps);
      shade.setArg(arg++, b_shadows);
      shade.setArg(arg++, b_dirs);
      shade.setArg(arg++, b_dirs);
      shade.setArg(arg++, b_lut);
      shade.setArg(arg++, cl_int(maps.width));
      shade.setArg(arg++, cl_int(maps.height));
      shade.setArg(arg++, cl_float(maps.height_max));
      shade.setArg(arg++, cl_float(maps.exposure));
      shade.setArg(arg++, cl_int(n_dirs));
      shade.setArg(arg++, cl_int(n_dirs));
      shade.setArg(arg++, cl_int(first));
      shade.setArg(arg++, cl_int(count));
      shade.setArg(arg++, cl_int(out.is_hdr() ? 1 : 0));
      shade.setArg(arg++, out.is_hdr() ? b_unused : b_out);
      shade.setArg(arg++, out.is_hdr() ? b_out : b_unused);
      dev.queue().enqueueNDRangeKernel(shade, cl::NullRange, cl::NDRange(round_up(size_t(count) * n_dirs, 64)));
      const size_t bytes = size_t(count) * pair_count * 3 * value_bytes, offset = size_t(first) * pair_count * 3;
      void* dst = out.is_hdr() ? static_cast<void*>(out.hdr_data().data() + offset)
                               : static_cast<void*>(out.ldr_data().data() + offset);
      dev.queue().enqueueReadBuffer(b_out, CL_TRUE, 0, bytes, dst);
      if (progress) progress(size_t(first + count), size_t(texels));
    }
  });
}

}  // namespace

const std::vector<SyntheticPreset>& synthetic_presets() {
  static const std::vector<SyntheticPreset> presets = [] {
    std::vector<SyntheticPreset> p;
    for (const auto& d : preset_defs()) p.push_back(d.info);
    return p;
  }();
  return presets;
}

MaterialMaps make_material(const std::string& preset, int size, uint64_t seed) {
  const PresetDef& def = find_preset(preset);
  if (size < 1 || size > 2048)
    throw InputError("synthetic sample size must be in 1..2048 (got " + std::to_string(size) + ")");
  Fields fields(size);
  def.make(fields, mix64(seed ^ 0x6274667671ULL));
  return pack(fields, def.exposure);
}

MeasuredSample render_material(const MaterialMaps& maps, Dynamic dynamic, RenderPath path,
                               const ProgressFn& progress) {
  if (maps.width < 1 || maps.height < 1 || maps.texels.size() != size_t(maps.width) * maps.height * kMaterialStride)
    throw InputError("material maps do not match their size");
  MeasuredSample out = make_bonn_sample(maps.width, maps.height, dynamic);
  if (path == RenderPath::Auto)
    path = ComputeDevice::get().uses_opencl() ? RenderPath::OpenCL : RenderPath::Reference;
  if (path == RenderPath::OpenCL)
    render_opencl(maps, out, progress);
  else
    render_reference(maps, out, progress);
  return out;
}

MeasuredSample synthesize(const SynthOptions& options) {
  return render_material(make_material(options.preset, options.size, options.seed), options.dynamic, options.path,
                         options.progress);
}

double mean_angular_variance(const MeasuredSample& sample) {
  const size_t pairs = sample.pair_count();
  if (sample.texel_count() == 0 || pairs == 0) return 0;
  double total = 0;
  for (size_t t = 0; t < sample.texel_count(); ++t) {
    double sum = 0, sum2 = 0;
    for (size_t p = 0; p < pairs; ++p) {
      const double y = 0.2126 * sample.value(t, p, 0) + 0.7152 * sample.value(t, p, 1) + 0.0722 * sample.value(t, p, 2);
      sum += y;
      sum2 += y * y;
    }
    const double mean = sum / double(pairs);
    total += std::max(0.0, sum2 / double(pairs) - mean * mean);
  }
  return total / double(sample.texel_count());
}

}  // namespace btfvq
