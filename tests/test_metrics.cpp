#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include <btfvq/error.h>
#include "pipeline/metrics/metrics.h"
#include "support/test_paths.h"

using namespace btfvq;

namespace {

std::filesystem::path golden_dir() { return test::source_dir() / "tests" / "golden"; }

// Data rows of a TSV file: skips '#' comment lines and the column header.
std::vector<std::vector<std::string>> read_tsv(const std::filesystem::path& path) {
  std::ifstream in(path);
  REQUIRE_MESSAGE(in, "cannot open " << path);
  std::vector<std::vector<std::string>> rows;
  std::string line;
  bool header = true;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    if (header) {
      header = false;
      continue;
    }
    std::vector<std::string> cells;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, '\t')) cells.push_back(cell);
    rows.push_back(cells);
  }
  return rows;
}

GrayImage read_pgm(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  REQUIRE_MESSAGE(in, "cannot open " << path);
  std::string magic;
  int w = 0, h = 0, maxval = 0;
  in >> magic >> w >> h >> maxval;
  REQUIRE(magic == "P5");
  REQUIRE(maxval == 255);
  in.get();  // the single whitespace byte before the raster
  std::vector<unsigned char> raw(size_t(w) * size_t(h));
  in.read(reinterpret_cast<char*>(raw.data()), std::streamsize(raw.size()));
  REQUIRE(in.gcount() == std::streamsize(raw.size()));
  GrayImage img(w, h);
  for (size_t i = 0; i < raw.size(); ++i) img.pixels[i] = float(raw[i]);
  return img;
}

GrayImage pattern(int w, int h, int seed) {
  GrayImage img(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) img.at(x, y) = float((x * 7 + y * 13 + seed * (x ^ y)) % 256);
  return img;
}

// SSIM of one window covering the whole image, straight from Wang et al. (Eq. 13 with the
// Gaussian-weighted statistics of Eqs. 14-16), written independently of the library.
double single_window_ssim(const GrayImage& a, const GrayImage& b) {
  auto weights = [](int n) {
    std::vector<double> w;
    double s = 0;
    for (int i = 0; i < n; ++i) {
      const double d = i - (n - 1) / 2.0;
      w.push_back(std::exp(-d * d / (2 * 1.5 * 1.5)));
      s += w.back();
    }
    for (double& v : w) v /= s;
    return w;
  };
  const auto wx = weights(a.width), wy = weights(a.height);
  double mx = 0, my = 0;
  for (int y = 0; y < a.height; ++y)
    for (int x = 0; x < a.width; ++x) {
      mx += wx[size_t(x)] * wy[size_t(y)] * a.at(x, y);
      my += wx[size_t(x)] * wy[size_t(y)] * b.at(x, y);
    }
  double vx = 0, vy = 0, cxy = 0;
  for (int y = 0; y < a.height; ++y)
    for (int x = 0; x < a.width; ++x) {
      const double w = wx[size_t(x)] * wy[size_t(y)];
      vx += w * (a.at(x, y) - mx) * (a.at(x, y) - mx);
      vy += w * (b.at(x, y) - my) * (b.at(x, y) - my);
      cxy += w * (a.at(x, y) - mx) * (b.at(x, y) - my);
    }
  const double c1 = 2.55 * 2.55, c2 = 7.65 * 7.65;
  return (2 * mx * my + c1) * (2 * cxy + c2) / ((mx * mx + my * my + c1) * (vx + vy + c2));
}

}  // namespace

TEST_CASE("MSSIM agrees with scikit-image's structural_similarity (Wang et al. settings) to 1e-4") {
  const auto rows = read_tsv(golden_dir() / "ssim_golden.tsv");
  REQUIRE(rows.size() >= 7);
  for (const auto& r : rows) {
    REQUIRE(r.size() == 6);
    INFO("pair " << r[0]);
    const GrayImage a = read_pgm(golden_dir() / r[1]), b = read_pgm(golden_dir() / r[2]);
    REQUIRE(a.width == std::stoi(r[3]));
    REQUIRE(a.height == std::stoi(r[4]));
    const double expected = std::stod(r[5]);
    CHECK(std::abs(mssim(a, b) - expected) < 1e-4);
    CHECK(std::abs(mssim(b, a) - expected) < 1e-4);
  }
}

TEST_CASE("The SSIM map covers exactly the windows inside the image") {
  const GrayImage a = pattern(40, 23, 3), b = pattern(40, 23, 5);
  const GrayImage m = ssim_map(a, b);
  CHECK(m.width == 30);
  CHECK(m.height == 13);
  double sum = 0;
  for (float v : m.pixels) sum += v;
  CHECK(sum / double(m.pixels.size()) == doctest::Approx(mssim(a, b)).epsilon(1e-6));
  CHECK(mssim(a, a) == doctest::Approx(1.0).epsilon(1e-12));
}

TEST_CASE("An image smaller than the window uses one window of the image size") {
  const GrayImage a = pattern(6, 9, 2), b = pattern(6, 9, 11);
  const GrayImage m = ssim_map(a, b);
  CHECK(m.width == 1);
  CHECK(m.height == 1);
  CHECK(mssim(a, b) == doctest::Approx(single_window_ssim(a, b)).epsilon(1e-9));
  // Only one axis small: 14 x 7 gives 4 x 1 windows of 11 x 7.
  const GrayImage m2 = ssim_map(pattern(14, 7, 1), pattern(14, 7, 4));
  CHECK(m2.width == 4);
  CHECK(m2.height == 1);
}

TEST_CASE("SSIM rejects images of different sizes and empty images") {
  CHECK_THROWS_AS(mssim(pattern(20, 20, 1), pattern(20, 21, 1)), InputError);
  CHECK_THROWS_AS(mssim(GrayImage(), GrayImage()), InputError);
}

TEST_CASE("PSNR over 8-bit values") {
  std::vector<uint8_t> a(300), b(300);
  for (size_t i = 0; i < a.size(); ++i) {
    a[i] = uint8_t(i % 255);
    b[i] = uint8_t(a[i] + 1);
  }
  // MSE 1: 20 log10(255).
  CHECK(psnr(a, b) == doctest::Approx(48.130803608679).epsilon(1e-12));
  // Half the values off by 255, half equal: MSE 255^2 / 2, PSNR 10 log10(2).
  std::vector<uint8_t> z(4, 0), w{255, 0, 255, 0};
  CHECK(psnr(z, w) == doctest::Approx(3.010299956640).epsilon(1e-12));
  CHECK(std::isinf(psnr(a, a)));
  CHECK(psnr(a, a) > 0);
  CHECK_THROWS_AS(psnr(a, std::span<const uint8_t>(b).first(10)), InputError);
  CHECK_THROWS_AS(psnr({}, {}), InputError);
}

TEST_CASE("CIEDE2000 reproduces all 34 pairs of Sharma, Wu and Dalal in both orders") {
  const auto rows = read_tsv(test::testdata_dir() / "ciede2000_sharma.tsv");
  REQUIRE(rows.size() == 34);
  for (size_t i = 0; i < rows.size(); ++i) {
    const auto& r = rows[i];
    REQUIRE(r.size() == 7);
    INFO("pair " << i + 1);
    const CieLab x{std::stod(r[0]), std::stod(r[1]), std::stod(r[2])};
    const CieLab y{std::stod(r[3]), std::stod(r[4]), std::stod(r[5])};
    const double expected = std::stod(r[6]);
    CHECK(std::abs(ciede2000(x, y) - expected) < 1e-4);
    CHECK(std::abs(ciede2000(y, x) - expected) < 1e-4);
  }
}

TEST_CASE("sRGB to CIELAB under D65") {
  // The white point maps to L = 100 with no chroma, black to 0.
  const CieLab w = srgb_to_lab({255, 255, 255});
  CHECK(w.l == doctest::Approx(100.0).epsilon(1e-6));
  CHECK(std::abs(w.a) < 1e-4);
  CHECK(std::abs(w.b) < 1e-4);
  const CieLab k = srgb_to_lab({0, 0, 0});
  CHECK(std::abs(k.l) < 1e-9);
  // scikit-image's rgb2lab uses a 6-digit matrix and the rounded constants 0.008856 / 7.787; the two
  // definitions differ by at most ~0.005 in L*, a*, b* over these colours.
  const auto rows = read_tsv(golden_dir() / "lab_golden.tsv");
  REQUIRE(rows.size() >= 12);
  for (const auto& r : rows) {
    REQUIRE(r.size() == 6);
    INFO("rgb " << r[0] << " " << r[1] << " " << r[2]);
    const CieLab lab = srgb_to_lab({std::stof(r[0]), std::stof(r[1]), std::stof(r[2])});
    CHECK(std::abs(lab.l - std::stod(r[3])) < 0.01);
    CHECK(std::abs(lab.a - std::stod(r[4])) < 0.01);
    CHECK(std::abs(lab.b - std::stod(r[5])) < 0.01);
  }
  // Values outside 0..255 are clamped.
  const CieLab over = srgb_to_lab({300, -5, 255});
  const CieLab clamped = srgb_to_lab({255, 0, 255});
  CHECK(over.l == clamped.l);
  CHECK(over.a == clamped.a);
}

namespace {

MeasuredSample small_sample(Dynamic dynamic, int w = 24, int h = 19) {
  // Three views with different light lists: pair indexing must not assume a square layout.
  std::vector<Direction> views{{0, 0}, {30, 0}, {60, 90}};
  std::vector<std::vector<Direction>> lights{{{0, 0}, {15, 0}}, {{45, 180}}, {{0, 0}, {30, 30}, {75, 15}}};
  return MeasuredSample(w, h, views, lights, dynamic);
}

uint8_t ref_value(size_t texel, size_t pair, int c) { return uint8_t((texel * 37 + pair * 53 + size_t(c) * 91) % 256); }
uint8_t test_value(size_t texel, size_t pair, int c) {
  const int v = ref_value(texel, pair, c) + int((texel * 7 + pair * 3 + size_t(c)) % 41) - 20;
  return uint8_t(std::clamp(v, 0, 255));
}

void fill_ldr(MeasuredSample& s, uint8_t (*f)(size_t, size_t, int)) {
  for (size_t t = 0; t < s.texel_count(); ++t)
    for (size_t p = 0; p < s.pair_count(); ++p)
      for (int c = 0; c < 3; ++c) s.ldr_data()[(t * s.pair_count() + p) * 3 + size_t(c)] = f(t, p, c);
}

}  // namespace

TEST_CASE("evaluate: every metric over every (view, light) image") {
  MeasuredSample ref = small_sample(Dynamic::LDR), test = small_sample(Dynamic::LDR);
  fill_ldr(ref, ref_value);
  fill_ldr(test, test_value);
  const EvaluationReport rep = evaluate(ref, test);
  REQUIRE(rep.images == 6);

  // The expected values, assembled image by image from the single-image metrics.
  const int W = ref.width(), H = ref.height();
  double sy = 0, scb = 0, scr = 0;
  std::vector<uint8_t> all_a, all_b;
  std::vector<double> de;
  for (size_t p = 0; p < ref.pair_count(); ++p) {
    GrayImage ya(W, H), yb(W, H), cba(W, H), cbb(W, H), cra(W, H), crb(W, H);
    for (size_t t = 0; t < ref.texel_count(); ++t) {
      const Rgb a{float(ref_value(t, p, 0)), float(ref_value(t, p, 1)), float(ref_value(t, p, 2))};
      const Rgb b{float(test_value(t, p, 0)), float(test_value(t, p, 1)), float(test_value(t, p, 2))};
      ya.pixels[t] = 0.299f * a.r + 0.587f * a.g + 0.114f * a.b;
      yb.pixels[t] = 0.299f * b.r + 0.587f * b.g + 0.114f * b.b;
      cba.pixels[t] = rgb_to_ycbcr(a).cb;
      cbb.pixels[t] = rgb_to_ycbcr(b).cb;
      cra.pixels[t] = rgb_to_ycbcr(a).cr;
      crb.pixels[t] = rgb_to_ycbcr(b).cr;
      for (int c = 0; c < 3; ++c) {
        all_a.push_back(ref_value(t, p, c));
        all_b.push_back(test_value(t, p, c));
      }
      de.push_back(ciede2000(srgb_to_lab(a), srgb_to_lab(b)));
    }
    sy += mssim(ya, yb) / 6;
    scb += mssim(cba, cbb) / 6;
    scr += mssim(cra, crb) / 6;
  }
  CHECK(rep.mssim_y == doctest::Approx(sy).epsilon(1e-9));
  CHECK(rep.mssim_cb == doctest::Approx(scb).epsilon(1e-9));
  CHECK(rep.mssim_cr == doctest::Approx(scr).epsilon(1e-9));
  CHECK(rep.mssim_y < 0.99);
  CHECK(rep.psnr == doctest::Approx(psnr(all_a, all_b)).epsilon(1e-9));
  double mean = 0;
  for (double d : de) mean += d / double(de.size());
  CHECK(rep.ciede2000_mean == doctest::Approx(mean).epsilon(1e-9));
  std::sort(de.begin(), de.end());
  const double p95 = de[size_t(std::ceil(0.95 * double(de.size()))) - 1];  // nearest rank
  CHECK(std::abs(rep.ciede2000_p95 - p95) <= kCiede2000Resolution / 2 + 1e-12);
  CHECK(rep.ciede2000_p95 > rep.ciede2000_mean);

  // The thread count changes nothing, not even the last bit.
  const EvaluationReport one = evaluate(ref, test, 1), three = evaluate(ref, test, 3);
  CHECK(one.mssim_y == rep.mssim_y);
  CHECK(three.mssim_cr == rep.mssim_cr);
  CHECK(one.ciede2000_mean == rep.ciede2000_mean);
  CHECK(three.psnr == rep.psnr);
  CHECK(three.ciede2000_p95 == rep.ciede2000_p95);
}

TEST_CASE("evaluate: identical samples are perfect") {
  MeasuredSample ref = small_sample(Dynamic::LDR);
  fill_ldr(ref, ref_value);
  const EvaluationReport rep = evaluate(ref, ref);
  CHECK(rep.mssim_y == doctest::Approx(1.0).epsilon(1e-12));
  CHECK(rep.mssim_cb == doctest::Approx(1.0).epsilon(1e-12));
  CHECK(std::isinf(rep.psnr));
  CHECK(rep.ciede2000_mean == 0.0);
  CHECK(rep.ciede2000_p95 == doctest::Approx(kCiede2000Resolution / 2));
}

TEST_CASE("evaluate: HDR samples are tone-mapped by 255 v^(1/2.2) before every metric") {
  MeasuredSample lref = small_sample(Dynamic::LDR), ltest = small_sample(Dynamic::LDR);
  fill_ldr(lref, ref_value);
  fill_ldr(ltest, test_value);
  MeasuredSample href = small_sample(Dynamic::HDR), htest = small_sample(Dynamic::HDR);
  for (size_t i = 0; i < lref.ldr_data().size(); ++i) {
    href.hdr_data()[i] = std::pow(lref.ldr_data()[i] / 255.0f, 2.2f);
    htest.hdr_data()[i] = std::pow(ltest.ldr_data()[i] / 255.0f, 2.2f);
  }
  // Radiance above 1 saturates at 255, negative radiance clips to 0.
  CHECK(display_value(4.0f, Dynamic::HDR) == 255.0f);
  CHECK(display_value(-1.0f, Dynamic::HDR) == 0.0f);
  CHECK(display_value(std::numeric_limits<float>::quiet_NaN(), Dynamic::HDR) == 0.0f);
  CHECK(display_value(std::numeric_limits<float>::infinity(), Dynamic::HDR) == 255.0f);
  CHECK(display_value(0.5f, Dynamic::HDR) == doctest::Approx(255 * std::pow(0.5, 1 / 2.2)).epsilon(1e-6));
  const EvaluationReport l = evaluate(lref, ltest), h = evaluate(href, htest);
  CHECK(h.mssim_y == doctest::Approx(l.mssim_y).epsilon(1e-5));
  CHECK(h.mssim_cr == doctest::Approx(l.mssim_cr).epsilon(1e-5));
  CHECK(h.psnr == doctest::Approx(l.psnr).epsilon(1e-4));
  CHECK(h.ciede2000_mean == doctest::Approx(l.ciede2000_mean).epsilon(1e-4));
}

TEST_CASE("evaluate: samples of different geometry are rejected") {
  const MeasuredSample ref = small_sample(Dynamic::LDR);
  CHECK_THROWS_AS(evaluate(ref, small_sample(Dynamic::LDR, 24, 20)), InputError);
  CHECK_THROWS_AS(evaluate(ref, small_sample(Dynamic::HDR)), InputError);
  CHECK_THROWS_AS(evaluate(ref, make_bonn_sample(24, 19, Dynamic::LDR)), InputError);
  std::vector<Direction> views{{0, 0}, {30, 0}, {60, 90}};
  std::vector<std::vector<Direction>> lights{{{0, 0}, {15, 0}}, {{45, 180}}, {{0, 0}, {30, 30}, {75, 20}}};
  try {
    evaluate(ref, MeasuredSample(24, 19, views, lights, Dynamic::LDR));
    FAIL("expected an InputError");
  } catch (const InputError& e) {
    CHECK(std::string(e.what()).find("view 2") != std::string::npos);
  }
}
