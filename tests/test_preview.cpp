// Preview renders (pipeline/decode/preview.h, `btfvq render --scene`): geometry, lights, options, the CLI.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "pipeline/io/btfbase.h"
#include "pipeline/format/database.h"
#include "pipeline/decode/decoder.h"
#include <btfvq/error.h>
#include "pipeline/decode/preview.h"
#include "support/image_file.h"
#include "support/test_paths.h"

using namespace btfvq;

namespace {
const Database& alu() {
  static const Database db = import_btfbase((test::testdata_dir() / "btfbase" / "alu").string());
  return db;
}
}  // namespace

TEST_CASE("plane lit from the camera: every pixel is the decoded value of its texel at light = view = (50, 270)") {
  // The plane is tilted 50 degrees about the image x axis (tangent = image x), so the camera (and a
  // light along the camera axis) sits at theta 50, phi 270 in its tangent frame.
  const Decoder dec(alu());
  PreviewOptions o;
  o.scene = PreviewScene::Plane;
  o.size = 48;
  o.tiles = 1;
  o.lights = {{{0, 0}, 1.0}};
  const std::vector<float> img = render_preview(dec, 0, o);
  REQUIRE(img.size() == size_t(48 * 48 * 3));
  const Material& m = alu().materials[0];
  double worst = 0;
  for (int py = 0; py < 48; py += 5)
    for (int px = 0; px < 48; px += 3) {
      const double u = (px + 0.5) / 48.0, v = (py + 0.5) / 48.0 / std::cos(50.0 * kDeg);
      const int tx = int(u * m.width), ty = int((v - std::floor(v)) * m.height);
      const Rgb want = dec.evaluate(0, tx, ty, {50, 270}, {50, 270});
      const float* got = &img[(size_t(py) * 48 + size_t(px)) * 3];
      worst = std::max({worst, double(std::abs(got[0] - want.r)), double(std::abs(got[1] - want.g)), double(std::abs(got[2] - want.b))});
    }
  CHECK(worst < 0.05);
}

TEST_CASE("sphere: background outside, lit side brighter, an environment of lights adds up") {
  const Decoder dec(alu());
  PreviewOptions o;
  o.size = 64;
  o.lights = {{{45, 135}, 1.0}};  // up-left, in front
  const std::vector<float> one = render_preview(dec, 0, o);
  auto px = [&](const std::vector<float>& img, int x, int y) { return img[(size_t(y) * 64 + size_t(x)) * 3 + 1]; };
  CHECK(px(one, 0, 0) == 40.0f);
  CHECK(px(one, 63, 63) == 40.0f);
  CHECK(px(one, 22, 22) > px(one, 52, 48) + 20);
  o.lights = preview_environment();
  const std::vector<float> env = render_preview(dec, 0, o);
  CHECK(px(env, 52, 48) > px(one, 52, 48));  // other lights reach the side turned away from the key light

  o.size = 8;
  CHECK_THROWS_AS(render_preview(dec, 0, o), InputError);
  o.size = 64;
  o.lights.clear();
  CHECK_THROWS_AS(render_preview(dec, 0, o), InputError);
  CHECK_THROWS_AS(render_preview(dec, 3, PreviewOptions{}), NotFoundError);
  CHECK_THROWS_AS(parse_preview_scene("cube"), InputError);
}

TEST_CASE("btfvq render --scene writes the preview as PNG; the per-direction mode still works") {
  const auto dir = test::scratch_dir("preview-cli");
  const auto db = dir / "alu.btfdb";
  write_database(alu(), db.string(), PackSettings::lossless());
  const std::string cli = (test::bin_dir() / "btfvq").string() + " render " + db.string() + " --material alu ";
  std::string out;
  REQUIRE_MESSAGE(test::run_command(cli + "--scene sphere --light 45,135 --size 64 --out " + (dir / "s.png").string(), &out) == 0, out);
  const test::Image image = test::read_image(dir / "s.png");
  REQUIRE(image.width == 64);
  REQUIRE(image.height == 64);
  REQUIRE(image.channels == 3);
  const std::vector<uint8_t>& pixels = image.pixels;
  PreviewOptions o;
  o.size = 64;
  const Decoder dec(alu());
  const std::vector<float> want = render_preview(dec, 0, o);
  for (size_t i = 0; i < pixels.size(); i += 97) CHECK(std::abs(double(pixels[i]) - std::clamp(double(want[i]), 0.0, 255.0)) <= 0.51);
  REQUIRE_MESSAGE(test::run_command(cli + "--scene plane --env --out " + (dir / "p.png").string(), &out) == 0, out);
  CHECK(std::filesystem::file_size(dir / "p.png") > 1000);
  CHECK(test::run_command(cli + "--scene cube --out " + (dir / "c.png").string(), &out) != 0);
  CHECK(out.find("cube") != std::string::npos);
  REQUIRE_MESSAGE(test::run_command(cli + "--light 30,0 --view 0,0 --out " + (dir / "d.png").string(), &out) == 0, out);
}
