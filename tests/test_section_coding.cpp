// Section encoding 2: the adaptive range coder, the per-field symbol models, and end to end on a
// compressed synthetic material (smaller than raw packed, decoded values bit-identical).
#include <doctest/doctest.h>

#include <cmath>
#include <cstring>
#include <random>

#include "pipeline/encode/compress.h"
#include "pipeline/format/database.h"
#include "pipeline/decode/decoder.h"
#include <btfvq/error.h>
#include "pipeline/format/packing.h"
#include "pipeline/format/range_coder.h"
#include "pipeline/format/section_coding.h"
#include "pipeline/io/synthetic.h"

using namespace btfvq;

namespace {

// A packed section: `header` bytes, then an index field of `n` values of `w` bits (row length `cols`)
// and a value field of n 8-bit codes; the values come from `gen(i)`.
template <class Gen>
std::vector<uint8_t> packed_section(size_t header, size_t n, int w, Gen gen) {
  std::vector<uint8_t> out;
  ByteWriter bw(out);
  for (size_t i = 0; i < header; ++i) bw.u8(uint8_t(i * 37));
  std::vector<uint32_t> v(n), codes(n);
  for (size_t i = 0; i < n; ++i) {
    v[i] = gen(i) & (w >= 32 ? 0xFFFFFFFFu : (1u << w) - 1);
    codes[i] = gen(i + 7) & 0xFF;
  }
  write_indices(bw, v.data(), n, w);
  bw.u8(1);  // Linear, 8 bits, min 0, max 1
  bw.u8(8);
  bw.f32(0.0f);
  bw.f32(1.0f);
  std::vector<uint8_t> packed;
  ByteWriter pw(packed);
  write_indices(pw, codes.data(), n, 8);
  out.insert(out.end(), packed.begin() + 1, packed.end());
  return out;
}

SectionShape shape_of(size_t header, size_t n, size_t cols) {
  return {header, {{FieldShape::Index, n, cols}, {FieldShape::Values, n, cols}}};
}

}  // namespace

TEST_CASE("the range coder round-trips skewed bits and rejects truncated streams") {
  std::mt19937 rng(1);
  std::vector<unsigned> bits;
  std::vector<int> which;
  for (int i = 0; i < 20000; ++i) {
    const int m = int(rng() % 4);  // four models with very different statistics
    which.push_back(m);
    const double p1 = m == 0 ? 0.01 : m == 1 ? 0.5 : m == 2 ? 0.9 : 0.999;
    bits.push_back(std::uniform_real_distribution<double>(0, 1)(rng) < p1 ? 1u : 0u);
  }
  std::vector<uint8_t> stream;
  {
    BitModel models[4] = {kBitModelInit, kBitModelInit, kBitModelInit, kBitModelInit};
    RangeEncoder e(stream);
    for (size_t i = 0; i < bits.size(); ++i) e.bit(models[which[i]], bits[i]);
    e.finish();
  }
  // Close to the entropy of the four sources (about 0.39 bits per bit), never below it.
  double entropy_bytes = 0;
  for (int m : which) {
    const double p1 = m == 0 ? 0.01 : m == 1 ? 0.5 : m == 2 ? 0.9 : 0.999;
    entropy_bytes -= (p1 * std::log2(p1) + (1 - p1) * std::log2(1 - p1)) / 8;
  }
  MESSAGE(bits.size() << " bits: " << stream.size() << " bytes, entropy " << entropy_bytes << " bytes");
  CHECK(double(stream.size()) > 0.97 * entropy_bytes);
  CHECK(double(stream.size()) < 1.08 * entropy_bytes);
  BitModel models[4] = {kBitModelInit, kBitModelInit, kBitModelInit, kBitModelInit};
  RangeDecoder d(stream.data(), stream.size(), "stream");
  for (size_t i = 0; i < bits.size(); ++i) REQUIRE(d.bit(models[which[i]]) == bits[i]);
  CHECK_NOTHROW(d.finish());

  auto decode_all = [&](const std::vector<uint8_t>& s) {
    BitModel m[4] = {kBitModelInit, kBitModelInit, kBitModelInit, kBitModelInit};
    RangeDecoder dd(s.data(), s.size(), "cut stream");
    for (size_t i = 0; i < bits.size(); ++i) dd.bit(m[which[i]]);
    dd.finish();
  };
  CHECK_THROWS_AS(decode_all(std::vector<uint8_t>(stream.begin(), stream.end() - 1)), CorruptError);
  auto longer = stream;
  longer.push_back(0);
  CHECK_THROWS_AS(decode_all(longer), CorruptError);
}

TEST_CASE("integer and symbol models round-trip every magnitude") {
  std::mt19937 rng(2);
  std::vector<uint32_t> values = {0, 1, 2, 3, 0xFFFFFFFFu, 0x80000000u, 0x7FFFFFFFu, 65535, 65536};
  for (int i = 0; i < 3000; ++i) values.push_back(uint32_t(rng()) >> (rng() % 32));
  std::vector<uint8_t> stream;
  {
    RangeEncoder e(stream);
    IntegerModel im;
    SymbolModel sm(12);
    for (uint32_t v : values) {
      im.encode(e, v);
      sm.encode(e, v & 0xFFF);
    }
    e.finish();
  }
  RangeDecoder d(stream.data(), stream.size(), "stream");
  IntegerModel im;
  SymbolModel sm(12);
  for (uint32_t v : values) {
    REQUIRE(im.decode(d) == v);
    REQUIRE(sm.decode(d) == (v & 0xFFF));
  }
  d.finish();
}

TEST_CASE("every symbol model round-trips fields of every width") {
  std::mt19937 rng(3);
  int coded = 0;
  for (int w = 1; w <= 32; ++w) {
    for (size_t cols : {size_t(1), size_t(7), size_t(16), size_t(33)}) {
      const size_t n = 5 * cols + 3;
      // Runs, repeated rows, small steps and noise: every branch of the models gets used.
      auto gen = [&](size_t i) {
        const size_t r = i / cols, c = i % cols;
        const uint32_t base = uint32_t(c / 3 + (r % 2) * 5);
        return (i % 11 == 0) ? uint32_t(rng()) : base + uint32_t(i % 4 == 0);
      };
      const auto raw = packed_section(5, n, w, gen);
      const SectionShape shape = shape_of(5, n, cols);
      for (int model = -1; model < 128; ++model) {
        const auto stored = model_encode(raw, shape, model);
        REQUIRE(stored.has_value());
        CAPTURE(w);
        CAPTURE(cols);
        CAPTURE(model);
        REQUIRE(model_decode(stored->data(), stored->size(), shape, raw.size(), "field") == raw);
        ++coded;
      }
    }
  }
  MESSAGE(coded << " (width, row length, model) combinations round-trip");
  // A section that does not have the shape, or non-zero padding bits, is not coded this way.
  auto raw = packed_section(5, 10, 3, [](size_t i) { return uint32_t(i); });
  CHECK(!model_encode(raw, shape_of(5, 11, 4)).has_value());
  CHECK(!model_encode(raw, shape_of(6, 10, 4)).has_value());
  raw[5 + 1 + 3] |= 0x80;  // the padding bits after the 30 index bits
  CHECK(!model_encode(raw, shape_of(5, 10, 4)).has_value());
}

TEST_CASE("damaged stored bytes are a CorruptError or other bytes, never a crash or an over-allocation") {
  std::mt19937 rng(4);
  const size_t cols = 16, n = 16 * 12;
  const auto raw = packed_section(9, n, 10, [](size_t i) { return uint32_t((i / 16) * 3 + (i % 16) / 4); });
  const SectionShape shape = shape_of(9, n, cols);
  const auto stored = model_encode(raw, shape).value();
  CHECK(stored.size() < raw.size() / 2);
  int rejected = 0, different = 0;
  for (size_t i = 0; i < stored.size(); ++i)
    for (uint8_t mask : {uint8_t(0x01), uint8_t(0x40), uint8_t(0xFF)}) {
      auto bad = stored;
      bad[i] ^= mask;
      try {
        different += model_decode(bad.data(), bad.size(), shape, raw.size(), "flip") != raw ? 1 : 0;
      } catch (const CorruptError&) {
        ++rejected;
      }
    }
  MESSAGE(rejected << " flips rejected, " << different << " decoded to other bytes (the CRC catches those)");
  CHECK(rejected > 0);
  for (size_t k = 0; k < stored.size(); ++k)
    CHECK_THROWS_AS(model_decode(stored.data(), k, shape, raw.size(), "cut"), CorruptError);
  // A raw length that the fields do not add up to, and a shape claiming far more values than fit.
  CHECK_THROWS_AS(model_decode(stored.data(), stored.size(), shape, raw.size() + 1, "len"), CorruptError);
  CHECK_THROWS_AS(model_decode(stored.data(), stored.size(), shape_of(9, size_t(1) << 40, cols), raw.size(), "huge"),
                  CorruptError);
}

TEST_CASE("a compressed synthetic material: range coded file much smaller than raw packed, same decoded bits") {
  SynthOptions o;
  o.preset = "wood";
  o.size = 24;
  Database db;
  compress_material(db, synthesize(o), "wood", {});
  PackSettings raw_packed, zstd;
  raw_packed.zstd_level = 0;
  raw_packed.range_coding = zstd.range_coding = false;
  const auto raw = serialize_database(db, raw_packed), z = serialize_database(db, zstd), coded = serialize_database(db);
  MESSAGE("wood 24 x 24: raw packed " << raw.size() << " bytes, zstd " << z.size() << ", range coded " << coded.size());
  CHECK(double(raw.size()) / double(coded.size()) > 1.25);  // measured +48 %; acceptance +20 %
  CHECK(coded.size() < z.size());
  const DatabaseHead head = parse_head(coded.data(), coded.size());
  int range_coded = 0;
  for (const auto& s : head.sections) range_coded += s.encoding == 2 ? 1 : 0;
  CHECK(range_coded >= 6);

  const Database a = parse_database(raw), b = parse_database(coded);
  CHECK(a.codebooks == b.codebooks);
  CHECK(a.materials == b.materials);
  const Decoder da(a), dbb(b);
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> theta(0, 85), phi(0, 360);
  std::uniform_int_distribution<int> xy(0, 23);
  int identical = 0;
  const int queries = 5000;
  for (int i = 0; i < queries; ++i) {
    const int x = xy(rng), y = xy(rng);
    const Direction l{theta(rng), phi(rng)}, v{theta(rng), phi(rng)};
    const Rgb p = da.evaluate(0, x, y, l, v), q = dbb.evaluate(0, x, y, l, v);
    identical += std::memcmp(&p, &q, sizeof p) == 0 ? 1 : 0;
  }
  CHECK(identical == queries);
  // Random access stays per section: each section decodes on its own from its stored bytes.
  const DatabaseHead raw_head = parse_head(raw.data(), raw.size());
  REQUIRE(raw_head.sections.size() == head.sections.size());
  for (size_t i = 0; i < head.sections.size(); ++i) {
    const SectionEntry& s = head.sections[i];
    if (s.encoding != 2) continue;
    const std::vector<uint8_t> section(coded.begin() + long(s.offset), coded.begin() + long(s.offset + s.length));
    const SectionEntry& r = raw_head.sections[i];
    const std::vector<uint8_t> expected(raw.begin() + long(r.offset), raw.begin() + long(r.offset + r.length));
    CHECK(decode_section_bytes(s, head.grid, section) == expected);
  }
}
