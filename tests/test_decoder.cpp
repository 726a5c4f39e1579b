#include <doctest/doctest.h>

#include <algorithm>
#include <ctime>
#include <cmath>
#include <random>

#include "pipeline/btfbase.h"
#include "pipeline/decoder.h"
#include "pipeline/opencl_runtime.h"
#include "support/test_paths.h"

using namespace btfvq;

namespace {

const Database& alu() {
  static const Database db = import_btfbase((test::testdata_dir() / "btfbase" / "alu").string());
  return db;
}
const Database& proposte() {
  static const Database db = import_btfbase((test::testdata_dir() / "btfbase" / "proposte").string());
  return db;
}

struct Known {
  int x, y;
  Direction light, view;
  Rgb rgb;
};

// FORMAT.md "Known values": decoded by an independent re-implementation of the original's rules.
const Known kAlu[] = {
    {0, 0, {0, 0}, {0, 0}, {261.51f, 263.54f, 259.34f}},      {10, 20, {60, 90}, {0, 0}, {62.66f, 64.64f, 60.54f}},
    {33, 7, {45, 120}, {30, 60}, {61.33f, 63.31f, 59.21f}},   {5, 40, {75, 345}, {75, 15}, {19.86f, 21.78f, 17.81f}},
    {63, 63, {15, 300}, {60, 240}, {76.56f, 78.53f, 74.45f}},
};
const Known kProposte[] = {
    {0, 0, {0, 0}, {0, 0}, {233.31f, 209.99f, 175.31f}},       {10, 20, {60, 90}, {0, 0}, {141.91f, 127.94f, 108.17f}},
    {33, 7, {45, 120}, {30, 60}, {205.27f, 192.56f, 174.63f}}, {5, 40, {75, 345}, {75, 15}, {179.94f, 167.17f, 149.14f}},
    {63, 63, {15, 300}, {60, 240}, {227.56f, 199.34f, 159.10f}},
};

void check_known(const Database& db, const Known* known, size_t n) {
  const Decoder dec(db);
  for (size_t i = 0; i < n; ++i) {
    const Known& k = known[i];
    const Rgb v = dec.evaluate(0, k.x, k.y, k.light, k.view);
    INFO("texel " << k.x << "," << k.y << " light " << k.light.theta << "," << k.light.phi << " view " << k.view.theta
                  << "," << k.view.phi << " -> " << v.r << " " << v.g << " " << v.b);
    CHECK(std::abs(v.r - k.rgb.r) <= 0.05f);
    CHECK(std::abs(v.g - k.rgb.g) <= 0.05f);
    CHECK(std::abs(v.b - k.rgb.b) <= 0.05f);
  }
}

// Random queries whose angles are exact 32-bit floats, so that the kernel (which receives floats)
// and the reference see the same inputs. Theta covers [0, 90] including both ends.
std::vector<DecodeQuery> random_queries(const Database& db, size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> theta(0.0f, 90.0f), phi(0.0f, 360.0f);
  std::uniform_int_distribution<int> coord(-300, 600);
  std::vector<DecodeQuery> q(n);
  for (size_t i = 0; i < n; ++i) {
    q[i].material = uint32_t(i % db.materials.size());
    q[i].x = coord(rng);
    q[i].y = coord(rng);
    q[i].light = {double(theta(rng)), double(phi(rng))};
    q[i].view = {double(theta(rng)), double(phi(rng))};
    if (i % 97 == 0) q[i].light.theta = 90.0;
    if (i % 89 == 0) q[i].view.theta = 90.0;
    if (i % 83 == 0) q[i].view.theta = 0.0;
  }
  return q;
}

bool close(float a, float b) { return std::abs(a - b) <= 1e-3f * std::max({1.0f, std::abs(a), std::abs(b)}); }

}  // namespace

TEST_CASE("alu decodes to the independently computed values of FORMAT.md") {
  check_known(alu(), kAlu, std::size(kAlu));
}

TEST_CASE("proposte decodes to the independently computed values of FORMAT.md") {
  check_known(proposte(), kProposte, std::size(kProposte));
}

TEST_CASE("directions below the horizon, wrapped texels and uncompressed texels") {
  const Decoder dec(alu());
  const Rgb inside = dec.evaluate(0, 10, 20, {60, 90}, {0, 0});
  CHECK(inside.r > 1.0f);
  const Rgb below_light = dec.evaluate(0, 10, 20, {90.5, 90}, {0, 0});
  const Rgb below_view = dec.evaluate(0, 10, 20, {60, 90}, {91, 0});
  const Rgb nan_light = dec.evaluate(0, 10, 20, {std::nan(""), 90}, {0, 0});
  const Rgb nan_phi = dec.evaluate(0, 10, 20, {60, 90}, {10, std::nan("")});
  CHECK(nan_light.r == 0.0f);
  CHECK(nan_phi.g == 0.0f);
  CHECK(below_light.r == 0.0f);
  CHECK(below_light.g == 0.0f);
  CHECK(below_view.b == 0.0f);
  const Rgb wrapped = dec.evaluate(0, 10 + 64, 20 - 128, {60, 90}, {0, 0});
  CHECK(wrapped.r == inside.r);
  CHECK(wrapped.g == inside.g);
  CHECK(wrapped.b == inside.b);
  // phi_v wraps: 360 is the same view as 0.
  const Rgb v0 = dec.evaluate(0, 3, 3, {30, 10}, {45, 0});
  const Rgb v360 = dec.evaluate(0, 3, 3, {30, 370}, {45, 360});
  CHECK(v0.r == doctest::Approx(v360.r).epsilon(1e-5));

  Database db = alu();
  db.materials[0].p6_index[20 * 64 + 10] = -1;
  const Decoder dec2(db);
  const Rgb none = dec2.evaluate(0, 10, 20, {60, 90}, {0, 0});
  CHECK(none.r == 0.0f);
  CHECK(none.g == 0.0f);
  CHECK(none.b == 0.0f);
  CHECK_THROWS_AS(dec2.evaluate(1, 0, 0, {0, 0}, {0, 0}), NotFoundError);
}

// At a light and view that sit exactly on grid nodes only one M entry and one P1 sample contribute,
// so the whole chain can be followed by hand through the tables.
TEST_CASE("on grid nodes the decoder is the chain of table look-ups, LDR and HDR") {
  for (Dynamic dyn : {Dynamic::LDR, Dynamic::HDR}) {
    Database db = alu();
    db.materials[0].dynamic = dyn;
    const Decoder dec(db);
    const Codebooks& k = db.codebooks;
    const Material& mat = db.materials[0];
    const int x = 17, y = 9;
    // View (0, 0): theta_v node 0, phi_v node 0. Light (0, 0): phi' = -90, so beta = 0 (node 5)
    // and alpha = 0 (node 5).
    const size_t texel = size_t(y) * 64 + size_t(x);
    const uint32_t p4 = uint32_t(mat.p6_index[texel]);
    const uint32_t p3 = k.p4_index.at(p4, 0);
    const uint32_t mi = k.p3_index.at(p3, 0);
    const uint32_t p2 = k.m.at(mi, 0), i2 = k.m.at(mi, 1);
    const float luma = k.p2_scale.at(p2, 5) * k.p1.at(k.p2_index.at(p2, 5), 5);
    const uint32_t ci = k.i1.at(k.i2.at(i2, 5), 5);
    const Rgb rgb = from_coding_space({luma, k.c.at(ci, 0), k.c.at(ci, 1)}, dyn == Dynamic::HDR);
    const double s = double(k.p4_scale.at(p4, 0)) * k.p3_scale.at(p3, 0) * mat.p6_scale[texel];
    const Rgb v = dec.evaluate(0, x, y, {0, 0}, {0, 0});
    INFO("HDR " << (dyn == Dynamic::HDR));
    CHECK(v.r == doctest::Approx(rgb.r * s).epsilon(1e-5));
    CHECK(v.g == doctest::Approx(rgb.g * s).epsilon(1e-5));
    CHECK(v.b == doctest::Approx(rgb.b * s).epsilon(1e-5));
    CHECK(std::abs(v.g) > 1.0f);  // not a comparison of zeros (LDR data read as LogLuv can go negative)
  }
}

TEST_CASE("the OpenCL batch decoder agrees with the C++ reference on random queries") {
  ComputeDevice::configure("auto");
  REQUIRE_MESSAGE(ComputeDevice::get().uses_opencl(), ComputeDevice::get().description());
  // Two materials sharing the code-books (the second an uncompressed-texel-riddled copy) exercise
  // the material table of the kernel.
  Database db = alu();
  Material second = db.materials[0];
  second.name = "alu-holes-hdr";
  second.dynamic = Dynamic::HDR;  // exercises the LogLuv branch of the kernel
  for (size_t i = 0; i < second.p6_index.size(); i += 7) second.p6_index[i] = -1;
  db.materials.push_back(second);
  const Decoder dec(db);
  const auto queries = random_queries(db, 6000, 1234);
  const auto ref = dec.decode_reference(queries);
  const auto gpu = dec.decode(queries);  // dispatches on the device: OpenCL here
  const auto gpu_again = dec.decode_opencl(queries);  // second call reuses the cached device buffers
  REQUIRE(gpu.size() == queries.size());
  size_t mismatches = 0, nonzero = 0;
  for (size_t i = 0; i < queries.size(); ++i) {
    const bool ok = close(ref[i].r, gpu[i].r) && close(ref[i].g, gpu[i].g) && close(ref[i].b, gpu[i].b);
    if (!ok && ++mismatches <= 5)
      MESSAGE("query " << i << ": reference " << ref[i].r << " " << ref[i].g << " " << ref[i].b << " OpenCL " << gpu[i].r
                       << " " << gpu[i].g << " " << gpu[i].b);
    nonzero += ref[i].r > 0;
    CHECK(gpu_again[i].r == gpu[i].r);
  }
  CHECK(mismatches == 0);
  CHECK(nonzero > queries.size() / 2);  // the comparison is not between zeros
}

TEST_CASE("the OpenCL batch decoder agrees with the reference on proposte") {
  REQUIRE(ComputeDevice::get().uses_opencl());
  const Decoder dec(proposte());
  const auto queries = random_queries(proposte(), 3000, 99);
  const auto ref = dec.decode_reference(queries);
  const auto gpu = dec.decode_opencl(queries);
  size_t mismatches = 0;
  for (size_t i = 0; i < queries.size(); ++i)
    mismatches += !(close(ref[i].r, gpu[i].r) && close(ref[i].g, gpu[i].g) && close(ref[i].b, gpu[i].b));
  CHECK(mismatches == 0);
}

TEST_CASE("decode() follows the configured device, and a reconfigured device gets fresh buffers") {
  const Decoder dec(alu());
  const auto queries = random_queries(alu(), 500, 3);
  ComputeDevice::configure("auto");
  REQUIRE(ComputeDevice::get().uses_opencl());
  const auto first = dec.decode_opencl(queries);
  ComputeDevice::configure("cpu-reference");
  const auto ref = dec.decode(queries);
  const auto expect = dec.decode_reference(queries);
  for (size_t i = 0; i < queries.size(); ++i) CHECK(ref[i].r == expect[i].r);
  CHECK_THROWS_AS(dec.decode_opencl(queries), DeviceError);
  ComputeDevice::configure("auto");
  REQUIRE(ComputeDevice::get().uses_opencl());
  const auto second = dec.decode(queries);  // new context: the code-books are uploaded again
  for (size_t i = 0; i < queries.size(); ++i) CHECK(second[i].g == first[i].g);
}
