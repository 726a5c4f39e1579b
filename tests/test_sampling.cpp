// Importance sampling of the light direction (paper Sec. 5.2) and albedo (eq. 6) through the
// renderer API, on the original compressor's databases (alu, proposte) and on a synthetic material
// compressed by our encoder and read back from its .btfdb file.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <thread>

#include "pipeline/io/btfbase.h"
#include "pipeline/encode/compress.h"
#include "pipeline/format/database.h"
#include "pipeline/decode/decoder.h"
#include <btfvq/error.h>
#include "pipeline/parametrization.h"
#include <btfvq/renderer_api.h>
#include "pipeline/decode/sampling.h"
#include "pipeline/io/synthetic.h"
#include "support/test_paths.h"

using namespace btfvq;

namespace {

const BtfDatabase& alu() {
  static const BtfDatabase db = BtfDatabase::from_memory(import_btfbase((test::testdata_dir() / "btfbase" / "alu").string()));
  return db;
}
const BtfDatabase& proposte() {
  static const BtfDatabase db =
      BtfDatabase::from_memory(import_btfbase((test::testdata_dir() / "btfbase" / "proposte").string()));
  return db;
}
// A synthetic preset compressed by our encoder.
Database compressed(const char* preset, int size, uint64_t seed, Dynamic dynamic, const char* name) {
  SynthOptions o;
  o.preset = preset;
  o.size = size;
  o.seed = seed;
  o.dynamic = dynamic;
  Database d;
  compress_material(d, synthesize(o), name, {});
  return d;
}

// Wood written and opened as a file.
const BtfDatabase& wood() {
  static const BtfDatabase db = [] {
    const auto path = test::scratch_dir("sampling") / "wood.btfdb";
    write_database(compressed("wood", 16, 3, Dynamic::LDR, "wood"), path.string());
    return BtfDatabase::open(path.string());
  }();
  return db;
}

// An HDR material (LogLuv coding space: the sampled luminance is the linear one).
const BtfDatabase& hdr_leather() {
  static const BtfDatabase db = BtfDatabase::from_memory(compressed("leather", 8, 5, Dynamic::HDR, "leather_hdr"));
  return db;
}

struct Case {
  const BtfDatabase* db;
  const char* material;
  double u, v;
};

std::vector<Case> cases() {
  return {{&alu(), "alu", 0.3, 0.6},
          {&proposte(), "proposte", 0.52, 0.17},
          {&wood(), "wood", 0.7, 0.4},
          {&hdr_leather(), "leather_hdr", 0.45, 0.8}};
}

const Direction kViews[] = {{0, 0}, {37, 71}, {66, 203}};

// Runs check(case, its material, view direction, view vector) for every case and view, with the
// material and the view's theta captured for failure messages.
template <size_t N, class F>
void for_each_view(const Direction (&views)[N], F check) {
  for (const Case& c : cases()) {
    const BtfMaterial mat = c.db->material(c.material);
    for (const Direction& vd : views) {
      const std::string material = c.material;
      CAPTURE(material);
      CAPTURE(vd.theta);
      check(c, mat, vd, to_vector(vd));
    }
  }
}

double angle(const Vec3& a, const Vec3& b) {
  const double d = a.x * b.x + a.y * b.y + a.z * b.z;
  const double la = std::sqrt(a.x * a.x + a.y * a.y + a.z * a.z), lb = std::sqrt(b.x * b.x + b.y * b.y + b.z * b.z);
  return std::acos(std::clamp(d / (la * lb), -1.0, 1.0));
}

// Upper 0.1% quantile of chi-square with k degrees of freedom (Wilson-Hilferty).
double chi2_critical(double k) {
  const double h = 2.0 / (9.0 * k);
  return k * std::pow(1.0 - h + 3.090232 * std::sqrt(h), 3.0);
}

// Integral over the hemisphere of f(direction) by the midpoint rule in (cos theta, phi): equal-area cells.
template <class F>
double integrate_hemisphere(int nz, int nphi, F f) {
  double sum = 0;
  for (int i = 0; i < nz; ++i) {
    const double z = (i + 0.5) / nz, r = std::sqrt(1.0 - z * z);
    for (int j = 0; j < nphi; ++j) {
      const double p = (j + 0.5) * 2.0 * kPi / nphi;
      sum += f(Vec3{r * std::cos(p), r * std::sin(p), z});
    }
  }
  return sum * 2.0 * kPi / (double(nz) * nphi);
}

}  // namespace

TEST_CASE("sampled directions follow the returned pdf (chi-square), and the sample's pdf is pdf()") {
  std::mt19937_64 rng(20261122);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for_each_view(kViews, [&](const Case& c, const BtfMaterial& mat, const Direction& vd, const Vec3& view) {
    // Bins: 20 x 20 in (alpha, sin beta) of the view's onion frame; d omega = d alpha d(sin beta),
    // so every bin has the same solid angle and pdf() integrates over it in those coordinates.
    constexpr int kA = 20, kS = 20, kSub = 4;
    std::vector<double> expected(kA * kS, 0.0);
    for (int a = 0; a < kA; ++a)
      for (int s = 0; s < kS; ++s)
        for (int i = 0; i < kSub; ++i)
          for (int j = 0; j < kSub; ++j) {
            const double alpha = -90.0 + (a + (i + 0.5) / kSub) * 180.0 / kA;
            const double sb = -1.0 + (s + (j + 0.5) / kSub) * 2.0 / kS;
            const Vec3 l = to_vector(from_onion({alpha, std::asin(sb) / kDeg}, vd.phi));
            expected[size_t(a * kS + s)] += mat.pdf(c.u, c.v, l, view) * (kPi / kA) * (2.0 / kS) / (kSub * kSub);
          }
    double total = 0;
    for (double e : expected) total += e;
    CHECK(total == doctest::Approx(1.0).epsilon(0.01));

    constexpr int kN = 100000;
    std::vector<double> observed(kA * kS, 0.0);
    double worst_pdf_mismatch = 0;
    for (int n = 0; n < kN; ++n) {
      const BtfSample smp = mat.sample(c.u, c.v, view, uni(rng), uni(rng));
      REQUIRE(smp.direction.z >= 0);
      REQUIRE(smp.pdf > 0);
      if (n % 50 == 0)
        worst_pdf_mismatch = std::max(worst_pdf_mismatch, std::abs(mat.pdf(c.u, c.v, smp.direction, view) / smp.pdf - 1.0));
      const OnionAngles o = to_onion(to_direction(smp.direction), vd.phi);
      const int a = std::clamp(int((o.alpha + 90.0) / 180.0 * kA), 0, kA - 1);
      const int s = std::clamp(int((std::sin(o.beta * kDeg) + 1.0) / 2.0 * kS), 0, kS - 1);
      observed[size_t(a * kS + s)] += 1;
    }
    CHECK(worst_pdf_mismatch < 1e-6);
    // Pearson's statistic; bins expecting fewer than 5 samples are pooled into one.
    double chi2 = 0, pooled_e = 0, pooled_o = 0;
    int bins = 0;
    for (size_t b = 0; b < expected.size(); ++b) {
      const double e = expected[b] / total * kN;
      if (e < 5) {
        pooled_e += e;
        pooled_o += observed[b];
        continue;
      }
      chi2 += (observed[b] - e) * (observed[b] - e) / e;
      ++bins;
    }
    if (pooled_e > 0) {
      chi2 += (pooled_o - pooled_e) * (pooled_o - pooled_e) / pooled_e;
      ++bins;
    }
    CAPTURE(chi2);
    CHECK(chi2 < chi2_critical(bins - 1));
  });
}

TEST_CASE("the pdf integrates to 1 over the hemisphere and is 0 below it") {
  for_each_view(kViews, [&](const Case& c, const BtfMaterial& mat, const Direction&, const Vec3& view) {
    const double integral = integrate_hemisphere(300, 600, [&](const Vec3& l) { return mat.pdf(c.u, c.v, l, view); });
    CHECK(integral == doctest::Approx(1.0).epsilon(0.01));
    CHECK(mat.pdf(c.u, c.v, Vec3{0.3, 0.2, -0.5}, view) == 0.0);
  });
}

TEST_CASE("the pdf follows the evaluated luminance: at every interior grid node pdf = (luminance + floors) / Z") {
  for_each_view(kViews, [&](const Case& c, const BtfMaterial& mat, const Direction& vd, const Vec3& view) {
    const AngularGrid& g = c.db->database().codebooks.grid;
    // The floors: kSamplingFloor x the mean luminance over all nodes, and kSamplingColumnFloor x
    // the mean over s (trapezoid) of the node's alpha column. Boundary nodes are evaluated just
    // inside the horizon, where the decoder still reads the node.
    std::vector<double> lum, pdf, column_mean(size_t(g.n_alpha), 0.0);
    std::vector<int> column_of;
    double mean = 0;
    for (int a = 0; a < g.n_alpha; ++a)
      for (int b = 0; b < g.n_beta; ++b) {
        const double alpha = std::clamp(g.alpha_node(a), -89.999999, 89.999999);
        const double beta = std::clamp(g.beta_node(b), -89.999999, 89.999999);
        const Direction l = from_onion({alpha, beta}, vd.phi);
        const double y = sampling_luminance(mat.evaluate(c.u, c.v, l, vd), mat.hdr());
        mean += y / (g.n_alpha * g.n_beta);
        column_mean[size_t(a)] += y * ((b == 0 || b == g.n_beta - 1) ? 0.5 : 1.0) / (g.n_beta - 1);
        if (a == 0 || b == 0 || a == g.n_alpha - 1 || b == g.n_beta - 1) continue;
        lum.push_back(y);
        column_of.push_back(a);
        pdf.push_back(mat.pdf(c.u, c.v, to_vector(l), view));
      }
    REQUIRE(mean > 0);
    double lo = 1e300, hi = 0;
    for (size_t i = 0; i < lum.size(); ++i) {
      const double ratio =
          pdf[i] / (lum[i] + kSamplingFloor * mean + kSamplingColumnFloor * column_mean[size_t(column_of[i])]);
      lo = std::min(lo, ratio);
      hi = std::max(hi, ratio);
    }
    CHECK(hi / lo < 1.001);
    // ... and it is not flat: the material's luminance varies over the hemisphere.
    CHECK(*std::max_element(pdf.begin(), pdf.end()) > 1.2 * *std::min_element(pdf.begin(), pdf.end()));
  });
}

TEST_CASE("continuity (Sec. 5.2): nearby (xi1, xi2) give nearby directions over the whole square") {
  for_each_view(kViews, [&](const Case& c, const BtfMaterial& mat, const Direction&, const Vec3& view) {
    // Over a 101 x 101 grid of pairs (edges included), the largest angle between the directions of
    // neighbours at distance d; a jump anywhere would keep it from shrinking with d. Near the poles
    // A and B (sin beta = +-1) the angle to the pole is ~ sqrt(2 (1 - sin beta)), so it shrinks
    // like sqrt(d) there (d / 100 -> angle / 10), linearly elsewhere. (Beside a very bright
    // column of an HDR material the slope is steep -- the region of (xi1, xi2) that maps to the
    // dark column is small -- so the checks use small d.)
    auto worst = [&](double d) {
      double w = 0;
      for (int i = 0; i <= 100; ++i)
        for (int j = 0; j <= 100; ++j) {
          const double x1 = std::min(i / 100.0, 1.0 - d), x2 = std::min(j / 100.0, 1.0 - d);
          const Vec3 p = mat.sample(c.u, c.v, view, x1, x2).direction;
          w = std::max({w, angle(p, mat.sample(c.u, c.v, view, x1 + d, x2).direction),
                        angle(p, mat.sample(c.u, c.v, view, x1, x2 + d).direction)});
        }
      return w;
    };
    const double w6 = worst(1e-6), w8 = worst(1e-8);
    CAPTURE(w6);
    CAPTURE(w8);
    CHECK(w6 < 0.05);
    CHECK(w8 < w6 / 5);
  });
}

TEST_CASE("albedo matches a brute-force integration of the evaluated reflectance within 1%") {
  for (const Case& c : cases()) {
    const BtfMaterial mat = c.db->material(c.material);
    for (const Direction& vd : {kViews[0], kViews[2]}) {
      const std::string material = c.material;
      CAPTURE(material);
      CAPTURE(vd.theta);
      const Vec3 view = to_vector(vd);
      const Rgb a = mat.albedo(c.u, c.v, view);
      double ref[3];
      for (int ch = 0; ch < 3; ++ch)
        ref[ch] = integrate_hemisphere(180, 360, [&](const Vec3& l) {
          const Rgb f = mat.evaluate(c.u, c.v, l, view);
          return (ch == 0 ? f.r : ch == 1 ? f.g : f.b) * l.z;
        });
      CHECK(a.r == doctest::Approx(ref[0]).epsilon(0.01));
      CHECK(a.g == doctest::Approx(ref[1]).epsilon(0.01));
      CHECK(a.b == doctest::Approx(ref[2]).epsilon(0.01));
      CHECK(ref[1] > 0);
    }
  }
  CHECK(alu().material("alu").albedo(0.1, 0.1, Vec3{0, 0.5, -1}).g == 0.0f);  // view below the horizon
}

TEST_CASE("no reflectance: a view below the horizon samples the hemisphere uniformly") {
  const BtfMaterial mat = alu().material("alu");
  const Vec3 below{0.2, 0.1, -0.9};
  const BtfSample s = mat.sample(0.5, 0.5, below, 0.3, 0.8);
  CHECK(s.direction.z >= 0);
  CHECK(s.pdf == doctest::Approx(1.0 / (2.0 * kPi)));
  CHECK(mat.pdf(0.5, 0.5, Vec3{0, 0, 1}, below) == doctest::Approx(1.0 / (2.0 * kPi)));
}

TEST_CASE("the renderer API: texture coordinates, names, errors, and concurrent use") {
  const BtfDatabase& db = proposte();
  const BtfMaterial mat = db.material("proposte");
  CHECK(db.material_names() == std::vector<std::string>{"proposte"});
  CHECK(mat.width() == 256);
  CHECK_FALSE(mat.hdr());
  CHECK_THROWS_AS(db.material("nope"), NotFoundError);
  CHECK_THROWS_AS(db.material(size_t(3)), NotFoundError);
  CHECK_THROWS_AS(BtfDatabase::open((test::scratch_dir("missing") / "none.btfdb").string()), InputError);
  // docs/btfbase-format.md: proposte texel (33, 7), light (45, 120), view (30, 60) decodes to 205.27, 192.56, 174.63.
  const Rgb v = mat.evaluate((33 + 0.5) / 256.0, (7 + 0.5) / 256.0, Direction{45, 120}, Direction{30, 60});
  CHECK(v.r == doctest::Approx(205.27).epsilon(0.0005));
  CHECK(v.g == doctest::Approx(192.56).epsilon(0.0005));
  CHECK(v.b == doctest::Approx(174.63).epsilon(0.0005));
  const Rgb w = mat.evaluate((33 + 256 + 0.9) / 256.0, (7 - 256 + 0.1) / 256.0, to_vector({45, 120}), to_vector({30, 60}));
  CHECK(w.g == doctest::Approx(v.g).epsilon(1e-6));  // tiles, and vectors mean the same directions

  // Two threads sampling at once get exactly what one thread gets.
  auto run = [&](std::vector<double>& out) {
    for (int i = 0; i < 2000; ++i) {
      const BtfSample s = mat.sample((i % 97) / 97.0, (i % 89) / 89.0, to_vector({double(i % 80), double(i * 7 % 360)}),
                                     (i % 101) / 101.0, (i % 103) / 103.0);
      out.push_back(s.pdf + s.direction.x);
    }
  };
  std::vector<double> one, a, b;
  run(one);
  std::thread ta([&] { run(a); }), tb([&] { run(b); });
  ta.join();
  tb.join();
  CHECK(a == one);
  CHECK(b == one);
}
