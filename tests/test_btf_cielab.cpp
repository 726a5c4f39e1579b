// BTF-CIELab (pipeline/metrics/btf_cielab.h): the definition's properties. Expected values come
// from outside the code under test: Table 1 of the paper typed in here, CIEDE2000 of the existing
// Sharma-checked ciede2000(), plain DFT sums, the geometry of the hemisphere.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <complex>
#include <functional>
#include <numeric>
#include <random>
#include <vector>

#include <fstream>
#include <nlohmann/json.hpp>

#include <btfvq/error.h>
#include "pipeline/metrics/btf_cielab.h"
#include "pipeline/metrics/fft.h"
#include "pipeline/metrics/metrics.h"
#include "support/test_paths.h"

using namespace btfvq;

namespace {

// Centre, the 15 and the 30 degree rings of the Bonn sampling: 19 directions, for small tests.
std::vector<Direction> inner19() { return std::vector<Direction>(bonn81().begin(), bonn81().begin() + 19); }

MeasuredSample make_sample(int w, int h, const std::vector<Direction>& views, const std::vector<Direction>& lights,
                           const std::function<Rgb(int x, int y, const Direction& view, const Direction& light)>& f) {
  MeasuredSample s(w, h, views, std::vector<std::vector<Direction>>(views.size(), lights), Dynamic::LDR);
  auto clamp8 = [](float v) { return uint8_t(std::clamp(std::lround(v), 0l, 255l)); };
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const size_t t = size_t(y) * size_t(w) + size_t(x);
      for (size_t v = 0; v < views.size(); ++v)
        for (size_t l = 0; l < lights.size(); ++l) {
          const Rgb c = f(x, y, views[v], lights[l]);
          uint8_t* p = s.ldr_data().data() + (t * s.pair_count() + s.pair_index(v, l)) * 3;
          p[0] = clamp8(c.r);
          p[1] = clamp8(c.g);
          p[2] = clamp8(c.b);
        }
    }
  return s;
}

// A material with spatial and angular structure.
Rgb textured(int x, int y, const Direction& v, const Direction& l) {
  const double shade = std::cos(l.theta * kDeg) * (0.7 + 0.3 * std::cos((l.phi - v.phi) * kDeg));
  const double grain = 0.5 + 0.5 * std::sin(0.9 * x + 0.4 * y) * std::cos(0.3 * x * y + v.theta * kDeg);
  return {float(40 + 180 * shade * grain), float(30 + 150 * shade), float(20 + 90 * grain)};
}

double relative(double a, double b) { return std::abs(a - b) / std::max(std::abs(b), 1e-12); }

}  // namespace

TEST_CASE("The kernel built from Table 1 has the table's weights and deviations and unit gain for a uniform field") {
  // Guthe et al., BTF-CIELab, Table 1: weight, sigma (degrees), delta (seconds).
  struct Row {
    CsfChannel channel;
    double w, sigma, delta;
  };
  const Row table[] = {{CsfChannel::Achromatic, 2.05962, 0.058406, 0.025135},
                       {CsfChannel::Achromatic, 1.29338, 0.038015, 0.054688},
                       {CsfChannel::Achromatic, -2.35300, 0.140856, 0.090229},
                       {CsfChannel::Chromatic, 0.67965, 0.096652, 0.069195},
                       {CsfChannel::Chromatic, 0.32035, 0.054198, 0.031830}};
  const auto& k = btf_cielab_components();
  REQUIRE(k.size() == 5);
  for (size_t i = 0; i < 5; ++i) {
    CHECK(k[i].channel == table[i].channel);
    CHECK(k[i].weight == table[i].w);
    CHECK(k[i].sigma_degrees == table[i].sigma);
    CHECK(k[i].delta_seconds == table[i].delta);
  }
  // Unit gain at zero frequency, and the sum of Gaussians exp(-pi^2 sigma^2 f^2) elsewhere:
  // band-pass for the achromatic channel (peak above 1 near 3 cycles per degree), low-pass for chroma.
  CHECK(csf_spatial_gain(CsfChannel::Achromatic, 0) == doctest::Approx(1.0).epsilon(1e-12));
  CHECK(csf_spatial_gain(CsfChannel::Chromatic, 0) == doctest::Approx(1.0).epsilon(1e-12));
  for (double f : {0.5, 3.0, 10.0}) {
    double a = 0, c = 0;
    for (const Row& r : table) {
      const double g = r.w * std::exp(-M_PI * M_PI * r.sigma * r.sigma * f * f);
      (r.channel == CsfChannel::Achromatic ? a : c) += g;
    }
    CHECK(csf_spatial_gain(CsfChannel::Achromatic, f) == doctest::Approx(a).epsilon(1e-12));
    CHECK(csf_spatial_gain(CsfChannel::Chromatic, f) == doctest::Approx(c).epsilon(1e-12));
  }
  CHECK(csf_spatial_gain(CsfChannel::Achromatic, 3.0) > 2.0);
  CHECK(csf_spatial_gain(CsfChannel::Chromatic, 3.0) < 0.6);
  CHECK(std::abs(csf_spatial_gain(CsfChannel::Achromatic, 30.0)) < 1e-3);

  // Angular part: each row of the convolution over the Bonn directions sums to 1 (a uniform field
  // stays uniform), and its weights fall off as exp(-(angle / (delta speed))^2) times the
  // neighbours' solid angles.
  const auto& dirs = bonn81();
  const std::vector<double> area = solid_angle_weights(dirs);
  const double speed = 400;
  for (const auto& row : table) {
    const double width = row.delta * speed;
    const AngularKernel kernel = angular_kernel(dirs, width);
    REQUIRE(kernel.rows.size() == dirs.size());
    for (size_t a = 0; a < dirs.size(); ++a) {
      double sum = 0, self = 0;
      for (const auto& [b, g] : kernel.rows[a]) {
        sum += g;
        if (b == a) self = g;
      }
      CHECK(sum == doctest::Approx(1.0).epsilon(1e-6));
      REQUIRE(self > 0);
      for (const auto& [b, g] : kernel.rows[a]) {
        const double angle = std::acos(std::clamp(
            std::cos(dirs[a].theta * kDeg) * std::cos(dirs[b].theta * kDeg) +
                std::sin(dirs[a].theta * kDeg) * std::sin(dirs[b].theta * kDeg) * std::cos((dirs[a].phi - dirs[b].phi) * kDeg),
            -1.0, 1.0)) / kDeg;
        const double expected = std::exp(-(angle / width) * (angle / width)) * area[b] / area[a];
        CHECK(g / self == doctest::Approx(expected).epsilon(1e-4));
      }
      // Nothing within the cut-off is left out.
      for (size_t b = 0; b < dirs.size(); ++b) {
        const double angle = angle_between(dirs[a], dirs[b]) / kDeg;
        const bool kept = std::any_of(kernel.rows[a].begin(), kernel.rows[a].end(), [&](auto& e) { return e.first == b; });
        if (std::exp(-(angle / width) * (angle / width)) > 2 * kAngularCutoff) CHECK(kept);
      }
    }
  }
  // Speed 0: no angular filtering at all.
  const AngularKernel id = angular_kernel(dirs, 0.0);
  for (size_t a = 0; a < dirs.size(); ++a) {
    REQUIRE(id.rows[a].size() == 1);
    CHECK(id.rows[a][0].first == a);
    CHECK(id.rows[a][0].second == 1.0f);
  }
}

TEST_CASE("Solid-angle weights of the Bonn directions: the Voronoi cells of the hemisphere") {
  const auto& dirs = bonn81();
  const std::vector<double> w = solid_angle_weights(dirs);
  CHECK(std::accumulate(w.begin(), w.end(), 0.0) == doctest::Approx(1.0));
  // The centre's cell is about the cap within 7.5 degrees (half way to the 15 degree ring):
  // 2 pi (1 - cos 7.5) of the hemisphere's 2 pi.
  CHECK(w[0] == doctest::Approx(1 - std::cos(7.5 * kDeg)).epsilon(0.25));
  // Directions of one ring have equal cells (to the lattice's resolution).
  for (size_t i = 7; i < 19; ++i) CHECK(w[i] == doctest::Approx(w[7]).epsilon(0.1));
  // The same weights in any order.
  std::vector<size_t> p(dirs.size());
  std::iota(p.begin(), p.end(), 0);
  std::mt19937 rng(3);
  std::shuffle(p.begin(), p.end(), rng);
  std::vector<Direction> shuffled;
  for (size_t i : p) shuffled.push_back(dirs[i]);
  const std::vector<double> ws = solid_angle_weights(shuffled);
  for (size_t i = 0; i < p.size(); ++i) CHECK(ws[i] == w[p[i]]);
}

TEST_CASE("Fft2d equals the plain DFT sum, for powers of two and other sizes") {
  for (auto [w, h] : {std::pair<size_t, size_t>{8, 4}, {16, 16}, {6, 5}, {1, 3}}) {
    INFO(w << " x " << h);
    std::vector<std::complex<float>> img(w * h), spec(w * h), copy;
    std::mt19937 rng(unsigned(w * 31 + h));
    std::uniform_real_distribution<float> u(-1, 1);
    for (auto& v : img) v = {u(rng), u(rng)};
    copy = img;
    Fft2d fft(w, h);
    fft.forward(img.data(), spec.data());
    for (size_t kx = 0; kx < w; ++kx)
      for (size_t ky = 0; ky < h; ++ky) {
        std::complex<double> sum = 0;
        for (size_t y = 0; y < h; ++y)
          for (size_t x = 0; x < w; ++x)
            sum += std::complex<double>(copy[y * w + x]) *
                   std::polar(1.0, -2 * M_PI * (double(kx * x) / double(w) + double(ky * y) / double(h)));
        CHECK(std::abs(std::complex<double>(spec[kx * h + ky]) - sum) < 1e-4 * double(w * h));
      }
    fft.inverse(spec.data(), img.data());
    for (size_t i = 0; i < img.size(); ++i) CHECK(std::abs(img[i] / float(w * h) - copy[i]) < 1e-5);
  }
}

TEST_CASE("Viewing conditions: RESOLUTION,SPEED with defaults at the centre of the paper's ranges") {
  const ViewingCondition d;
  CHECK(d.resolution == doctest::Approx(std::sqrt(2.0 * 100.0)));
  CHECK(d.speed == doctest::Approx(std::sqrt(10.0 * 1000.0)));
  CHECK(parse_viewing_condition("50,300").resolution == 50);
  CHECK(parse_viewing_condition("50,300").speed == 300);
  CHECK(parse_viewing_condition("30").speed == d.speed);
  CHECK(parse_viewing_condition(",0").resolution == d.resolution);
  CHECK(parse_viewing_condition(",0").speed == 0);
  CHECK_THROWS_AS(parse_viewing_condition("fast"), InputError);
  CHECK_THROWS_AS(parse_viewing_condition("0,100"), InputError);
  CHECK_THROWS_AS(parse_viewing_condition("10,-1"), InputError);
  CHECK_THROWS_AS(parse_viewing_condition("10,100x"), InputError);
}

TEST_CASE("Identical BTFs give 0") {
  const MeasuredSample a = make_sample(16, 12, inner19(), inner19(), textured);
  const MeasuredSample b = make_sample(16, 12, inner19(), inner19(), textured);
  for (const char* cond : {"", "60,1000", "2,10"}) {
    INFO(cond);
    BtfCielabOptions o;
    o.condition = parse_viewing_condition(cond);
    const BtfCielabReport r = btf_cielab(a, b, o);
    CHECK(r.mean == 0.0);
    CHECK(r.rms == 0.0);
    CHECK(r.stddev == 0.0);
    CHECK(r.pairs == 19 * 19);
  }
}

TEST_CASE("A uniform colour shift of a large uniform patch gives CIEDE2000 of the shift") {
  const Rgb base{120, 90, 60};
  for (const Rgb shift : {Rgb{125, 88, 70}, Rgb{120, 90, 60 + 20}, Rgb{100, 100, 100}}) {
    const MeasuredSample a = make_sample(32, 32, inner19(), inner19(), [&](int, int, auto&, auto&) { return base; });
    const MeasuredSample b = make_sample(32, 32, inner19(), inner19(), [&](int, int, auto&, auto&) { return shift; });
    const double expected = ciede2000(srgb_to_lab(base), srgb_to_lab(shift));
    for (const char* cond : {"", "100,1000", "2,10"}) {
      INFO(cond << " expected " << expected);
      BtfCielabOptions o;
      o.condition = parse_viewing_condition(cond);
      const BtfCielabReport r = btf_cielab(a, b, o);
      CHECK(relative(r.mean, expected) < 0.02);
      CHECK(relative(r.rms, expected) < 0.02);
      CHECK(r.stddev < 0.01 * expected);
    }
  }
}

TEST_CASE("Texel-scale white noise scores lower than a smooth error of the same RMS") {
  // Grey reference; the errors are luminance errors constant over the directions, of equal RGB RMS.
  const int n = 64;
  std::mt19937 rng(7);
  std::vector<float> noise(size_t(n) * n);
  for (float& v : noise) v = (rng() & 1) ? 12.0f : -12.0f;
  const auto grey = [](int, int, auto&, auto&) { return Rgb{128, 128, 128}; };
  const auto noisy = [&](int x, int y, auto&, auto&) {
    const float g = 128 + noise[size_t(y) * n + size_t(x)];
    return Rgb{g, g, g};
  };
  const auto smooth = [&](int x, int, auto&, auto&) {
    const float g = 128 + float(12 * std::sqrt(2.0) * std::sin(2 * M_PI * x / n));
    return Rgb{g, g, g};
  };
  const std::vector<Direction> dirs(bonn81().begin(), bonn81().begin() + 7);
  const MeasuredSample ref = make_sample(n, n, dirs, dirs, grey);
  const MeasuredSample a = make_sample(n, n, dirs, dirs, noisy), b = make_sample(n, n, dirs, dirs, smooth);
  // The two errors have the same RGB RMS (within the rounding to 8 bits) and about the same plain
  // CIEDE2000, so only the filter tells them apart.
  auto rms = [&](const MeasuredSample& s) {
    double sum = 0;
    for (size_t i = 0; i < s.ldr_data().size(); ++i) sum += std::pow(double(s.ldr_data()[i]) - 128.0, 2);
    return std::sqrt(sum / double(s.ldr_data().size()));
  };
  REQUIRE(relative(rms(a), rms(b)) < 0.03);
  const EvaluationReport pa = evaluate(ref, a), pb = evaluate(ref, b);
  REQUIRE(relative(pa.ciede2000_mean, pb.ciede2000_mean) < 0.3);
  // Texels small on the retina (paper Sec. 3.4: up to 100 texels per degree): noise at a texel's
  // scale lies beyond the contrast sensitivity, the smooth error does not.
  for (const char* cond : {"50,100", "100,100"}) {
    INFO(cond);
    BtfCielabOptions o;
    o.condition = parse_viewing_condition(cond);
    const BtfCielabReport rn = btf_cielab(ref, a, o), rs = btf_cielab(ref, b, o);
    INFO("noise " << rn.mean << ", smooth " << rs.mean);
    CHECK(rn.mean < 0.5 * rs.mean);
    CHECK(rn.rms < 0.5 * rs.rms);
    // The smooth error (one period over the patch, below 2 cycles per degree here) keeps at least
    // its plain CIEDE2000: the achromatic sensitivity only rises from 1 at zero frequency.
    CHECK(rs.mean > 0.95 * pb.ciede2000_mean);
  }
}

TEST_CASE("The value does not depend on the order in which the measured directions are stored") {
  const auto& dirs = bonn81();
  const auto error = [](int x, int y, const Direction& v, const Direction& l) {
    Rgb c = textured(x, y, v, l);
    // An angular error (a lobe that moves with the light) and a spatial one.
    const float e = float(25 * std::exp(-std::pow((l.phi - v.phi - 180) / 40.0, 2)) + 6 * ((x * 5 + y * 3) % 4));
    return Rgb{c.r + e, c.g - 0.5f * e, c.b + 0.3f * e};
  };
  const MeasuredSample ref = make_sample(8, 8, dirs, dirs, textured), test = make_sample(8, 8, dirs, dirs, error);
  std::vector<Direction> pv(dirs), pl(dirs);
  std::mt19937 rng(11);
  std::shuffle(pv.begin(), pv.end(), rng);
  std::shuffle(pl.begin(), pl.end(), rng);
  const MeasuredSample ref2 = make_sample(8, 8, pv, pl, textured), test2 = make_sample(8, 8, pv, pl, error);
  for (const char* cond : {"", "20,1000"}) {
    INFO(cond);
    BtfCielabOptions o;
    o.condition = parse_viewing_condition(cond);
    const BtfCielabReport r1 = btf_cielab(ref, test, o), r2 = btf_cielab(ref2, test2, o);
    CHECK(r1.mean > 0.5);
    CHECK(relative(r2.mean, r1.mean) < 1e-5);
    CHECK(relative(r2.rms, r1.rms) < 1e-5);
    CHECK(relative(r2.stddev, r1.stddev) < 1e-4);
  }
  // The angular filter matters for this error: without it (speed 0) the value differs.
  BtfCielabOptions still, moving;
  still.condition = parse_viewing_condition("20,0");
  moving.condition = parse_viewing_condition("20,1000");
  CHECK(relative(btf_cielab(ref, test, still).mean, btf_cielab(ref, test, moving).mean) > 0.02);
}

TEST_CASE("The result does not depend on the threads or the memory budget (the light blocks)") {
  const MeasuredSample a = make_sample(16, 8, inner19(), inner19(), textured);
  const MeasuredSample b = make_sample(16, 8, inner19(), inner19(), [](int x, int y, auto& v, auto& l) {
    Rgb c = textured(x, y, v, l);
    return Rgb{c.r + float((x * y) % 7), c.g, c.b - 3};
  });
  BtfCielabOptions one;
  one.threads = 1;
  one.memory_budget = 1;  // one light per pass
  BtfCielabOptions many;
  many.threads = 4;
  const BtfCielabReport r1 = btf_cielab(a, b, one), r2 = btf_cielab(a, b, many);
  CHECK(r1.light_blocks == 19);
  CHECK(r2.light_blocks == 1);
  CHECK(r1.mean == r2.mean);
  CHECK(r1.rms == r2.rms);
}

TEST_CASE("Samples of different geometry, or views with their own light lists, are refused") {
  const MeasuredSample a = make_sample(8, 8, inner19(), inner19(), textured);
  const MeasuredSample b = make_sample(8, 4, inner19(), inner19(), textured);
  CHECK_THROWS_AS(btf_cielab(a, b), InputError);
  std::vector<std::vector<Direction>> lights(2, inner19());
  lights[1].pop_back();
  const MeasuredSample c(4, 4, {{0, 0}, {15, 0}}, lights, Dynamic::LDR);
  CHECK_THROWS_AS(btf_cielab(c, c), InputError);
}

TEST_CASE("btfvq eval --metric btf-cielab adds its object to the JSON and leaves the rest as it was") {
  const auto dir = test::scratch_dir("btf-cielab-eval");
  const std::string cli = (test::bin_dir() / "btfvq").string();
  const std::string zip = (dir / "l.zip").string(), db = (dir / "l.btfdb").string();
  std::string out;
  REQUIRE_MESSAGE(test::run_command(cli + " synth --preset leather --size 16 --seed 1 --out " + zip, &out) == 0, out);
  REQUIRE_MESSAGE(test::run_command(cli + " compress " + zip + " --db " + db + " --name m", &out) == 0, out);
  const std::string eval = cli + " eval " + db + " --material m --reference " + zip;
  REQUIRE_MESSAGE(test::run_command(eval + " --json " + (dir / "plain.json").string(), &out) == 0, out);
  CHECK(out.find("BTF-CIELab") == std::string::npos);
  REQUIRE_MESSAGE(test::run_command(eval + " --metric btf-cielab:30,200 --json " + (dir / "cielab.json").string(), &out) == 0, out);
  CHECK(out.find("BTF-CIELab:") != std::string::npos);
  nlohmann::json plain = nlohmann::json::parse(std::ifstream(dir / "plain.json"));
  nlohmann::json with = nlohmann::json::parse(std::ifstream(dir / "cielab.json"));
  CHECK_FALSE(plain.contains("btf_cielab"));
  REQUIRE(with.contains("btf_cielab"));
  const nlohmann::json b = with["btf_cielab"];
  with.erase("btf_cielab");
  CHECK(with == plain);
  CHECK(b["resolution"].get<double>() == 30);
  CHECK(b["speed"].get<double>() == 200);
  CHECK(b["mean"].get<double>() > 0);
  CHECK(b["rms"].get<double>() >= b["mean"].get<double>());
  CHECK(b["seconds"].get<double>() > 0);
  CHECK(test::run_command(eval + " --metric btf-cielab:fast", &out) != 0);
  CHECK(test::run_command(eval + " --metric psnr", &out) != 0);
}
