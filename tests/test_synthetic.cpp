#include <archive.h>
#include <archive_entry.h>
#include <doctest/doctest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <regex>
#include <set>
#include <string>
#include <vector>

#include <btfvq/error.h>
#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/io/sample_io.h"
#include "pipeline/io/synthetic.h"
#include "support/test_paths.h"

using namespace btfvq;

namespace {

double luminance(const MeasuredSample& s, size_t texel, size_t pair) {
  return 0.2126 * s.value(texel, pair, 0) + 0.7152 * s.value(texel, pair, 1) + 0.0722 * s.value(texel, pair, 2);
}

size_t bonn_index(double theta, double phi) {
  const auto& d = bonn81();
  for (size_t i = 0; i < d.size(); ++i)
    if (d[i].theta == theta && d[i].phi == phi) return i;
  FAIL("no Bonn direction " << theta << "/" << phi);
  return 0;
}

}  // namespace

TEST_CASE("the OpenCL kernel and the C++ reference render the same values for every preset") {
  ComputeDevice::configure("auto");
  REQUIRE_MESSAGE(ComputeDevice::get().uses_opencl(), ComputeDevice::get().description());
  for (const auto& preset : synthetic_presets()) {
    CAPTURE(preset.name);
    const auto maps = make_material(preset.name, 16, 7);

    const auto cl_ldr = render_material(maps, Dynamic::LDR, RenderPath::OpenCL);
    const auto ref_ldr = render_material(maps, Dynamic::LDR, RenderPath::Reference);
    REQUIRE(cl_ldr.ldr_data().size() == size_t(16 * 16 * 6561 * 3));
    REQUIRE(ref_ldr.ldr_data().size() == cl_ldr.ldr_data().size());
    size_t close = 0;
    int worst = 0;
    for (size_t i = 0; i < cl_ldr.ldr_data().size(); ++i) {
      const int d = std::abs(int(cl_ldr.ldr_data()[i]) - int(ref_ldr.ldr_data()[i]));
      close += d <= 1;
      worst = std::max(worst, d);
    }
    MESSAGE(preset.name << ": " << cl_ldr.ldr_data().size() - close << " LDR values differ by more than 1, worst " << worst);
    CHECK(double(close) >= 0.999 * double(cl_ldr.ldr_data().size()));
    CHECK(worst <= 16);

    const auto cl_hdr = render_material(maps, Dynamic::HDR, RenderPath::OpenCL);
    const auto ref_hdr = render_material(maps, Dynamic::HDR, RenderPath::Reference);
    REQUIRE(cl_hdr.hdr_data().size() == ref_hdr.hdr_data().size());
    size_t agree = 0, finite = 0;
    for (size_t i = 0; i < cl_hdr.hdr_data().size(); ++i) {
      const float a = cl_hdr.hdr_data()[i], b = ref_hdr.hdr_data()[i];
      finite += std::isfinite(a) && a >= 0;
      agree += std::abs(a - b) <= 1e-3f * std::max(std::abs(a), std::abs(b)) + 1e-6f;
    }
    CHECK(finite == cl_hdr.hdr_data().size());
    CHECK(double(agree) >= 0.999 * double(cl_hdr.hdr_data().size()));
  }
}

TEST_CASE("the same seed gives the same bytes, another seed another material") {
  REQUIRE(ComputeDevice::get().uses_opencl());
  for (const std::string preset : {"foil", "wool"}) {
    CAPTURE(preset);
    const auto a = make_material(preset, 24, 42), b = make_material(preset, 24, 42), c = make_material(preset, 24, 43);
    CHECK(a.texels == b.texels);
    CHECK(a.texels != c.texels);
    const auto ra = render_material(a, Dynamic::LDR), rb = render_material(b, Dynamic::LDR);
    const auto rc = render_material(c, Dynamic::LDR);
    CHECK(ra.ldr_data() == rb.ldr_data());
    CHECK(ra.ldr_data() != rc.ldr_data());
  }
}

TEST_CASE("presets differ measurably: wool varies far more with the directions than tile, none clips or is dark") {
  REQUIRE(ComputeDevice::get().uses_opencl());
  double variance_tile = 0, variance_wool = 0;
  for (const auto& preset : synthetic_presets()) {
    CAPTURE(preset.name);
    const auto s = synthesize({preset.name, 16, 3, Dynamic::LDR, RenderPath::Auto, {}});
    const auto& v = s.ldr_data();
    const double clipped = double(std::count(v.begin(), v.end(), uint8_t(255))) / double(v.size());
    double mean = 0;
    for (uint8_t x : v) mean += x;
    mean /= double(v.size());
    const double variance = mean_angular_variance(s);
    MESSAGE(preset.name << ": angular variance " << variance << ", mean " << mean << ", clipped " << clipped);
    CHECK(clipped < 0.02);
    CHECK(mean > 30);
    CHECK(mean < 200);
    CHECK(variance > 50);
    if (preset.name == "tile") variance_tile = variance;
    if (preset.name == "wool") variance_wool = variance;
  }
  CHECK(variance_wool > 2.0 * variance_tile);
}

TEST_CASE("the renderer shows the physics: mirror highlight on the tile, parallax and shadows on wool") {
  REQUIRE(ComputeDevice::get().uses_opencl());
  const auto tile = synthesize({"tile", 16, 1, Dynamic::HDR, RenderPath::Auto, {}});
  const size_t view = bonn_index(45, 0);
  const size_t mirror = tile.pair_index(view, bonn_index(45, 180)), retro = tile.pair_index(view, bonn_index(45, 0));
  double at_mirror = 0, at_retro = 0;
  for (size_t t = 0; t < tile.texel_count(); ++t) {
    at_mirror += luminance(tile, t, mirror);
    at_retro += luminance(tile, t, retro);
  }
  CHECK(at_mirror > 1.8 * at_retro);  // the glaze's highlight lies in the mirror direction

  // Wool seen from the top under a grazing light: some texels are in the shadow of fibres, some lit.
  const auto wool = synthesize({"wool", 32, 1, Dynamic::HDR, RenderPath::Auto, {}});
  const size_t grazing = wool.pair_index(0, bonn_index(75, 90));
  double lo = 1e9, hi = 0;
  for (size_t t = 0; t < wool.texel_count(); ++t) {
    lo = std::min(lo, luminance(wool, t, grazing));
    hi = std::max(hi, luminance(wool, t, grazing));
  }
  CHECK(hi > 10 * lo);
  // Parallax: the image seen at 75 degrees is not the top view (the visible points move).
  const size_t top = wool.pair_index(0, 0), oblique = wool.pair_index(bonn_index(75, 0), 0);
  double moved = 0;
  for (size_t t = 0; t < wool.texel_count(); ++t)
    moved += std::abs(wool.value(t, top, 0) / std::max(1e-6f, wool.value(t, oblique, 0)) - 1);
  CHECK(moved / double(wool.texel_count()) > 0.1);
}

TEST_CASE("maps tile: the seam is no rougher than the interior") {
  const auto m = make_material("leather", 64, 5);
  double seam = 0, inside = 0;
  for (int y = 0; y < m.height; ++y) {
    seam += std::abs(m.at(m.width - 1, y, 0) - m.at(0, y, 0));
    inside += std::abs(m.at(31, y, 0) - m.at(32, y, 0));
  }
  CHECK(seam < 3 * inside + 1e-3);
}

TEST_CASE("bad presets and sizes are rejected with a clear message") {
  try {
    make_material("velvet", 16, 1);
    FAIL("expected InputError");
  } catch (const InputError& e) {
    const std::string what = e.what();
    CHECK(what.find("velvet") != std::string::npos);
    for (const auto& p : synthetic_presets()) CHECK(what.find(p.name) != std::string::npos);
  }
  CHECK_THROWS_AS(make_material("wool", 0, 1), InputError);
  CHECK_THROWS_AS(make_material("wool", 2049, 1), InputError);
  CHECK(synthetic_presets().size() >= 6);
}

namespace {

// Base names of the images of a UBO2003 zip (libarchive), or of the .jpg files under a directory.
std::vector<std::string> image_names(const std::filesystem::path& path) {
  std::vector<std::string> names;
  if (std::filesystem::is_directory(path)) {
    for (const auto& e : std::filesystem::recursive_directory_iterator(path))
      if (e.is_regular_file()) names.push_back(e.path().filename().string());
    return names;
  }
  archive* a = archive_read_new();
  archive_read_support_format_zip(a);
  REQUIRE(archive_read_open_filename(a, path.c_str(), 1 << 16) == ARCHIVE_OK);
  archive_entry* entry = nullptr;
  while (archive_read_next_header(a, &entry) == ARCHIVE_OK) {
    if (archive_entry_filetype(entry) != AE_IFREG) continue;
    const std::string name = archive_entry_pathname(entry);
    names.push_back(name.substr(name.rfind('/') + 1));
  }
  archive_read_free(a);
  return names;
}

// Every name is "NNNNN tlTTT plPPP tvTTT pvPPP.jpg", the running numbers are distinct, and the
// (light, view) pairs are exactly the 81 x 81 Bonn directions.
void check_bonn_names(const std::vector<std::string>& names) {
  REQUIRE(names.size() == 6561);
  const std::regex pattern(R"(^(\d{5}) tl(\d{3}) pl(\d{3}) tv(\d{3}) pv(\d{3})\.jpg$)");
  std::set<int> indices;
  std::set<std::array<int, 4>> pairs;
  for (const auto& n : names) {
    std::smatch m;
    REQUIRE_MESSAGE(std::regex_match(n, m, pattern), n);
    indices.insert(std::stoi(m[1]));
    pairs.insert({std::stoi(m[2]), std::stoi(m[3]), std::stoi(m[4]), std::stoi(m[5])});
  }
  CHECK(indices.size() == 6561);
  std::set<std::array<int, 4>> expected;
  for (const auto& v : bonn81())
    for (const auto& l : bonn81()) expected.insert({int(l.theta), int(l.phi), int(v.theta), int(v.phi)});
  CHECK(pairs == expected);
}

std::string btfvq_command() { return (btfvq::test::bin_dir() / "btfvq").string(); }

}  // namespace

TEST_CASE("btfvq synth writes a zip and a directory holding the 6561 Bonn images") {
  const auto dir = btfvq::test::scratch_dir("synth-cli");
  for (const std::string target : {"wool.zip", "wool_dir"}) {
    CAPTURE(target);
    const auto out_path = dir / target;
    std::string out;
    const int rc = btfvq::test::run_command(
        btfvq_command() + " synth --preset wool --size 16 --seed 3 --out '" + out_path.string() + "'", &out);
    REQUIRE_MESSAGE(rc == 0, out);
    CHECK(out.find("render") != std::string::npos);
    CHECK(out.find("write") != std::string::npos);
    CHECK(out.find(out_path.string()) != std::string::npos);
    check_bonn_names(image_names(out_path));

    // What was written reads back as the rendered sample (JPEG-close), direction by direction.
    const auto loaded = load_sample(out_path.string());
    const auto rendered = synthesize({"wool", 16, 3, Dynamic::LDR, RenderPath::Auto, {}});
    REQUIRE(loaded.texel_count() == rendered.texel_count());
    REQUIRE(loaded.pair_count() == rendered.pair_count());
    double diff = 0;
    for (size_t v = 0; v < loaded.view_count(); ++v)
      for (size_t l = 0; l < loaded.lights(v).size(); ++l) {
        const auto& dv = loaded.views()[v];
        const auto& dl = loaded.lights(v)[l];
        const size_t p = loaded.pair_index(v, l), q = rendered.pair_index(bonn_index(dv.theta, dv.phi),
                                                                           bonn_index(dl.theta, dl.phi));
        for (size_t t = 0; t < loaded.texel_count(); ++t)
          for (int c = 0; c < 3; ++c) diff += std::abs(loaded.value(t, p, c) - rendered.value(t, q, c));
      }
    CHECK(diff / double(loaded.texel_count() * loaded.pair_count() * 3) < 3.0);
  }
}

TEST_CASE("btfvq synth rejects an unknown preset (listing the presets) and sizes outside 1..2048") {
  const auto dir = btfvq::test::scratch_dir("synth-cli-bad");
  std::string out;
  CHECK(btfvq::test::run_command(btfvq_command() + " synth --preset velvet --out " + (dir / "x.zip").string(), &out) ==
        2);
  for (const auto& p : synthetic_presets()) CHECK(out.find(p.name) != std::string::npos);
  for (const std::string size : {"0", "2049", "abc"}) {
    CHECK(btfvq::test::run_command(
              btfvq_command() + " synth --preset tile --size " + size + " --out " + (dir / "y.zip").string(), &out) == 2);
    CHECK(out.find("--size") != std::string::npos);
  }
  CHECK(std::filesystem::is_empty(dir));
}
