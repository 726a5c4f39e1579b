#include <doctest/doctest.h>

#include <algorithm>
#include <ctime>
#include <cmath>
#include <limits>
#include <random>

#include "pipeline/io/btfbase.h"
#include "pipeline/decode/decoder.h"
#include "pipeline/runtime/opencl_runtime.h"
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

// docs/btfbase-format.md "Known values": decoded by an independent re-implementation of the original's rules.
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

// The kernel computes in float, the reference in double: over 2^21 random queries on alu and proposte
// they differ by at most ~8e-5 relative (bench_decoder's last column), so 2e-4 leaves room for
// rounding and still catches a wrong weight or node (which moves values by percents).
bool close(float a, float b) { return std::abs(a - b) <= 2e-4f * std::max({1.0f, std::abs(a), std::abs(b)}); }

size_t mismatches(const std::vector<Rgb>& ref, const std::vector<Rgb>& got) {
  size_t bad = 0;
  for (size_t i = 0; i < ref.size(); ++i) {
    const bool ok = close(ref[i].r, got[i].r) && close(ref[i].g, got[i].g) && close(ref[i].b, got[i].b);
    if (!ok && ++bad <= 5)
      MESSAGE("query " << i << ": reference " << ref[i].r << " " << ref[i].g << " " << ref[i].b << " OpenCL " << got[i].r
                       << " " << got[i].g << " " << got[i].b);
  }
  return bad;
}

}  // namespace

TEST_CASE("alu decodes to the independently computed values of docs/btfbase-format.md") {
  check_known(alu(), kAlu, std::size(kAlu));
}

TEST_CASE("proposte decodes to the independently computed values of docs/btfbase-format.md") {
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
  size_t nonzero = 0;
  for (size_t i = 0; i < queries.size(); ++i) {
    nonzero += ref[i].r > 0;
    CHECK(gpu_again[i].r == gpu[i].r);
  }
  CHECK(mismatches(ref, gpu) == 0);
  CHECK(nonzero > queries.size() / 2);  // the comparison is not between zeros
}

TEST_CASE("the OpenCL batch decoder agrees with the reference on proposte") {
  REQUIRE(ComputeDevice::get().uses_opencl());
  const Decoder dec(proposte());
  const auto queries = random_queries(proposte(), 3000, 99);
  const auto ref = dec.decode_reference(queries);
  const auto gpu = dec.decode_opencl(queries);
  CHECK(mismatches(ref, gpu) == 0);
}

// Near the pole of the onion parametrization (light at grazing theta with phi' = phi_i - phi_v - 90
// close to 0 or 180, so sin(beta) -> +-1) alpha = asin(y / cos(beta)) is ill-conditioned: the
// kernel's float arithmetic must still land on the reference's alpha cell and weight. (Not closer
// than ~0.003 deg to the pole: there the double reference itself loses alpha to the cancellation in
// sqrt(1 - sin^2(beta)), e.g. 0.04 deg of alpha at theta 90 and 0.001 deg from the pole, while the
// kernel's atan2 form stays exact.)
TEST_CASE("the OpenCL batch decoder agrees with the reference near the pole and on undecodable queries") {
  REQUIRE(ComputeDevice::get().uses_opencl());
  const Decoder dec(proposte());
  std::vector<DecodeQuery> q;
  for (float theta : {80.0f, 88.0f, 89.5f, 89.99f, 89.999f, 90.0f})
    for (float dphi : {-3.0f, -0.5f, -0.01f, -0.003f, 0.0f, 0.003f, 0.01f, 0.5f, 3.0f})
      for (float pole : {0.0f, 180.0f})
        for (float view_phi : {0.0f, 37.5f, 200.0f}) {
          const float light_phi = view_phi + 90.0f + pole + dphi;
          q.push_back({0, int(q.size()) % 256, int(q.size()) / 256, {double(theta), double(light_phi)}, {30.0, double(view_phi)}});
        }
  const size_t decodable = q.size();
  // Below the horizon, NaN angles, and negative texel coordinates (wrapped).
  q.push_back({0, 5, 5, {90.5, 10}, {10, 10}});
  q.push_back({0, 5, 5, {10, 10}, {91, 10}});
  q.push_back({0, 5, 5, {std::nan(""), 10}, {10, 10}});
  q.push_back({0, 5, 5, {10, std::nan("")}, {10, 10}});
  q.push_back({0, 5, 5, {10, 10}, {10, std::numeric_limits<double>::infinity()}});
  q.push_back({0, -5, -300, {40, 10}, {20, 350}});
  const auto ref = dec.decode_reference(q);
  const auto gpu = dec.decode_opencl(q);
  CHECK(mismatches(ref, gpu) == 0);
  for (size_t i = decodable; i + 1 < q.size(); ++i) {
    CHECK(gpu[i].r == 0.0f);
    CHECK(gpu[i].g == 0.0f);
    CHECK(gpu[i].b == 0.0f);
  }
  CHECK(gpu.back().g > 1.0f);
  size_t lit = 0;
  for (size_t i = 0; i < decodable; ++i) lit += ref[i].g > 1.0f;
  CHECK(lit == decodable);  // grazing light on proposte is not black: the comparison is not between zeros
}

// More than one chunk (2^20 queries per launch): the second, partly filled chunk reuses the
// first one's buffers.
TEST_CASE("the OpenCL batch decoder agrees with the reference across chunks") {
  REQUIRE(ComputeDevice::get().uses_opencl());
  const Decoder dec(alu());
  const auto q = random_queries(alu(), (size_t(1) << 20) + 1500, 11);
  const auto ref = dec.decode_reference(q);
  const auto gpu = dec.decode_opencl(q);
  REQUIRE(gpu.size() == q.size());
  CHECK(mismatches(ref, gpu) == 0);
}

// A renderer's batch: whole images under one light and view, large enough to take several
// work-groups and a partly filled last one.
TEST_CASE("the OpenCL batch decoder agrees with the reference on whole images") {
  REQUIRE(ComputeDevice::get().uses_opencl());
  const Decoder dec(alu());
  std::vector<DecodeQuery> q;
  for (const auto& [light, view] : {std::pair{Direction{45, 120}, Direction{30, 60}}, std::pair{Direction{75, 345}, Direction{75, 15}},
                                    std::pair{Direction{0, 0}, Direction{90, 0}}})
    for (int y = 0; y < 64; ++y)
      for (int x = 0; x < 64; ++x) q.push_back({0, x, y, light, view});
  q.resize(q.size() - 77);
  const auto ref = dec.decode_reference(q);
  const auto gpu = dec.decode_opencl(q);
  REQUIRE(gpu.size() == q.size());
  CHECK(mismatches(ref, gpu) == 0);
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

TEST_CASE("decode(n, query, out) gives decode(queries)'s values on both devices, and NotFoundError past the end") {
  const Database db = alu();
  const Decoder dec(db);
  const auto queries = random_queries(db, 70000, 17);  // more than one part of the packing loop
  const auto source = [&](size_t i) { return queries[i]; };
  for (const char* device : {"auto", "cpu-reference"}) {
    ComputeDevice::configure(device);
    const auto expect = dec.decode(queries);
    std::vector<Rgb> got(queries.size(), Rgb{-1, -1, -1});
    dec.decode(queries.size(), source, got.data());
    size_t same = 0;
    for (size_t i = 0; i < queries.size(); ++i)
      same += got[i].r == expect[i].r && got[i].g == expect[i].g && got[i].b == expect[i].b;
    CHECK_MESSAGE(same == queries.size(), device);
    auto bad = queries;
    bad[4000].material = 7;
    CHECK_THROWS_AS(dec.decode(bad.size(), [&](size_t i) { return bad[i]; }, got.data()), NotFoundError);
  }
  ComputeDevice::configure("auto");
  REQUIRE(ComputeDevice::get().uses_opencl());
}
