#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>

#include "pipeline/format/database.h"
#include <btfvq/error.h>
#include "pipeline/format/packing.h"
#include "support/test_paths.h"

using namespace btfvq;

namespace {

struct Counts {
  size_t p1, c, i1, i2, p2, m, p3, p4;
};

float uniform(std::mt19937& rng, float lo, float hi) { return std::uniform_real_distribution<float>(lo, hi)(rng); }
uint32_t pick(std::mt19937& rng, size_t n) { return std::uniform_int_distribution<uint32_t>(0, uint32_t(n - 1))(rng); }

// Appends random rows with valid indices and value ranges like the real alu database (docs/btfbase-format.md).
void append_rows(Database& db, std::mt19937& rng, const Counts& n) {
  Codebooks& k = db.codebooks;
  const AngularGrid& g = k.grid;
  for (size_t r = 0; r < n.p1; ++r) {
    std::vector<float> v(size_t(g.n_beta));
    float sum = 0;
    for (float& x : v) sum += (x = uniform(rng, 0.015f, 0.28f));
    for (float& x : v) x /= sum;
    k.p1.append(v.data());
  }
  for (size_t r = 0; r < n.c; ++r) {
    float ab[2] = {uniform(rng, 110, 140), uniform(rng, 110, 140)};
    k.c.append(ab);
  }
  auto index_rows = [&](Table<uint32_t>& t, size_t rows, size_t target) {
    std::vector<uint32_t> v(t.cols());
    for (size_t r = 0; r < rows; ++r) {
      for (auto& x : v) x = pick(rng, target);
      t.append(v.data());
    }
  };
  auto scale_rows = [&](Table<float>& t, size_t rows, float lo, float hi) {
    std::vector<float> v(t.cols());
    for (size_t r = 0; r < rows; ++r) {
      for (auto& x : v) x = uniform(rng, lo, hi);
      t.append(v.data());
    }
  };
  index_rows(k.i1, n.i1, k.c.rows());
  index_rows(k.i2, n.i2, k.i1.rows());
  index_rows(k.p2_index, n.p2, k.p1.rows());
  scale_rows(k.p2_scale, n.p2, 293, 1919);
  for (size_t r = 0; r < n.m; ++r) {
    uint32_t v[2] = {pick(rng, k.p2_index.rows()), pick(rng, k.i2.rows())};
    k.m.append(v);
  }
  index_rows(k.p3_index, n.p3, k.m.rows());
  scale_rows(k.p3_scale, n.p3, 0.82f, 1.12f);
  index_rows(k.p4_index, n.p4, k.p3_index.rows());
  scale_rows(k.p4_scale, n.p4, 0.997f, 1.026f);
}

Material random_material(std::mt19937& rng, const std::string& name, int w, int h, size_t p4_rows,
                         Dynamic dyn = Dynamic::LDR) {
  Material m;
  m.name = name;
  m.width = w;
  m.height = h;
  m.dynamic = dyn;
  m.raw_bytes = uint64_t(w) * h * 81 * 81 * 3;
  for (int i = 0; i < w * h; ++i) {
    m.p6_index.push_back(i == 1 ? -1 : int32_t(pick(rng, p4_rows)));
    m.p6_scale.push_back(i == 1 ? 0.0f : uniform(rng, 0.92f, 1.09f));
  }
  return m;
}

Database make_database(std::mt19937& rng, AngularGrid g, const Counts& n, int materials, int w, int h) {
  Database db;
  db.codebooks = Codebooks(g);
  append_rows(db, rng, n);
  for (int i = 0; i < materials; ++i)
    db.materials.push_back(random_material(rng, "mat" + std::to_string(i), w, h, db.codebooks.p4_index.rows()));
  return db;
}

std::vector<uint8_t> file_bytes(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

uint64_t packed(uint64_t n, uint64_t bits) { return (n * bits + 7) / 8; }
uint64_t ceil_log2(uint64_t s) {
  uint64_t b = 1;
  while ((uint64_t(1) << b) < s) ++b;
  return b;
}

// Expected file size of a single-version database, from the formulas of docs/format.md.
uint64_t expected_size(const Database& db, int value_bits_p1, int value_bits_c, int scale_bits) {
  const auto& k = db.codebooks;
  const uint64_t index_field = 1, value_field = 10, chunk_header = 16;
  const uint64_t g_b = uint64_t(k.grid.n_beta), g_a = uint64_t(k.grid.n_alpha), g_t = uint64_t(k.grid.n_theta_v),
                 g_p = uint64_t(k.grid.n_phi_v);
  uint64_t sections = 0, entries = 0;
  auto chunk = [&](uint64_t body) {
    sections += chunk_header + body;
    entries += 44;
  };
  chunk(value_field + packed(k.p1.rows() * g_b, uint64_t(value_bits_p1)));
  chunk(value_field + packed(k.c.rows() * 2, uint64_t(value_bits_c)));
  chunk(index_field + packed(k.i1.rows() * g_b, ceil_log2(k.c.rows())));
  chunk(index_field + packed(k.i2.rows() * g_a, ceil_log2(k.i1.rows())));
  chunk(index_field + packed(k.p2_index.rows() * g_a, ceil_log2(k.p1.rows())) + value_field +
        packed(k.p2_index.rows() * g_a, uint64_t(scale_bits)));
  chunk(2 * index_field + packed(k.m.rows(), ceil_log2(k.p2_index.rows())) + packed(k.m.rows(), ceil_log2(k.i2.rows())));
  chunk(index_field + packed(k.p3_index.rows() * g_t, ceil_log2(k.m.rows())) + value_field +
        packed(k.p3_index.rows() * g_t, uint64_t(scale_bits)));
  chunk(index_field + packed(k.p4_index.rows() * g_p, ceil_log2(k.p3_index.rows())) + value_field +
        packed(k.p4_index.rows() * g_p, uint64_t(scale_bits)));
  for (const auto& m : db.materials) {
    const uint64_t n = m.p6_index.size();
    sections += 2 + m.name.size() + 4 + 4 + 1 + 8 + index_field + packed(n, ceil_log2(k.p4_index.rows() + 1)) +
                value_field + packed(n, uint64_t(scale_bits));
    entries += 44 + m.name.size();
  }
  return 56 + 52 + entries + 8 + sections;
}

uint64_t raw_float_bytes(const Database& db) {
  const auto& k = db.codebooks;
  uint64_t n = k.p1.data().size() + k.c.data().size() + k.i1.data().size() + k.i2.data().size() +
               k.p2_index.data().size() + k.p2_scale.data().size() + k.m.data().size() + k.p3_index.data().size() +
               k.p3_scale.data().size() + k.p4_index.data().size() + k.p4_scale.data().size();
  for (const auto& m : db.materials) n += m.p6_index.size() + m.p6_scale.size();
  return 4 * n;
}

const Counts kMedium{200, 5, 20, 6, 300, 320, 120, 20};

// Raw packed sections only (encoding 0): the sizes docs/format.md's formulas give.
PackSettings without_zstd(PackSettings s = {}) {
  s.zstd_level = 0;
  s.range_coding = false;
  return s;
}

// zstd alone (encodings 0 and 1): what format version 1 files written before encoding 2 hold.
PackSettings zstd_only(PackSettings s = {}) {
  s.range_coding = false;
  return s;
}

}  // namespace

TEST_CASE("CRC-64/XZ and index widths match their definitions") {
  const std::string check = "123456789";
  CHECK(crc64(reinterpret_cast<const uint8_t*>(check.data()), check.size()) == 0x995DC9BBDF1939FAull);
  CHECK(index_bits(0) == 1);
  CHECK(index_bits(1) == 1);
  CHECK(index_bits(2) == 1);
  CHECK(index_bits(3) == 2);
  CHECK(index_bits(4) == 2);
  CHECK(index_bits(5) == 3);
  CHECK(index_bits(256) == 8);
  CHECK(index_bits(257) == 9);
}

TEST_CASE("bit packing is LSB-first and round-trips every width") {
  std::vector<uint8_t> out;
  ByteWriter w(out);
  const uint32_t v[3] = {5, 2, 7};  // 3 bits each: 101, 010, 111 -> bits 0..8 = 1,0,1, 0,1,0, 1,1,1
  write_indices(w, v, 3, 3);
  REQUIRE(out.size() == 3);
  CHECK(out[0] == 3);
  CHECK(out[1] == 0b11010101);
  CHECK(out[2] == 0b1);
  std::mt19937 rng(7);
  for (int width = 1; width <= 32; ++width) {
    std::vector<uint32_t> values(37);
    const uint64_t limit = uint64_t(1) << width;
    for (auto& x : values) x = uint32_t(std::uniform_int_distribution<uint64_t>(0, limit - 1)(rng));
    std::vector<uint8_t> buf;
    ByteWriter bw(buf);
    write_indices(bw, values.data(), values.size(), width);
    CHECK(buf.size() == 1 + (37 * size_t(width) + 7) / 8);
    ByteReader r(buf.data(), buf.size(), "test");
    CHECK(read_indices(r, values.size(), width, limit, "v") == values);
  }
}

TEST_CASE("write then read equals the quantized in-memory database; writing is deterministic") {
  std::mt19937 rng(1);
  Database db = make_database(rng, AngularGrid{}, kMedium, 2, 16, 12);
  const auto dir = test::scratch_dir("roundtrip");
  const auto path = (dir / "a.btfdb").string();
  write_database(db, path);
  CHECK(is_database_file(path));

  Database quantized = db;
  publish_version(quantized);
  REQUIRE(quantized.versions.size() == 1);
  CHECK(!(quantized.codebooks == db.codebooks));  // the defaults are lossy
  const Database back = read_database(path);
  CHECK(back == quantized);
  // A published, quantized database rewrites to the very same bytes; quantizing again changes nothing.
  CHECK(serialize_database(quantized) == file_bytes(path));
  Database again = quantized;
  again.versions.clear();
  quantize_new_rows(again);
  CHECK(again.codebooks == quantized.codebooks);
  CHECK(again.materials == quantized.materials);

  // Bit widths are minimal: without entropy coding the file size follows the spec's formula exactly.
  const auto size = serialize_database(db, without_zstd()).size();
  CHECK(size == expected_size(db, 8, 16, 8));
  CHECK(std::filesystem::file_size(path) <= size);
  const uint64_t raw = raw_float_bytes(db);
  MESSAGE("default settings: " << size << " bytes vs " << raw << " bytes as 32-bit values (1:" << double(raw) / double(size) << ")");

  const DatabaseInfo info = inspect_database(path);
  CHECK(info.head.version == 1);
  CHECK(info.head.sections.size() == 10);
  REQUIRE(info.materials.size() == 2);
  CHECK(info.materials[1].name == "mat1");
  CHECK(info.materials[1].width == 16);
  CHECK(info.materials[1].height == 12);
  CHECK(info.codebook_rows[CodebookId::P2] == 300);
  CHECK(info.codebook_rows[CodebookId::M] == 320);
}

TEST_CASE("lossless settings store an imported database bit for bit") {
  std::mt19937 rng(2);
  Database db = make_database(rng, AngularGrid{}, kMedium, 2, 8, 8);
  const auto path = (test::scratch_dir("lossless") / "l.btfdb").string();
  write_database(db, path, PackSettings::lossless());
  const Database back = read_database(path);
  CHECK(back.codebooks == db.codebooks);
  CHECK(back.materials == db.materials);
  CHECK(serialize_database(db, without_zstd(PackSettings::lossless())).size() == expected_size(db, 32, 32, 32));
  MESSAGE("lossless: " << std::filesystem::file_size(path) << " bytes vs " << raw_float_bytes(db) << " as 32-bit values");
}

TEST_CASE("append-only versions: every section of version 1 is byte-identical in version 2") {
  std::mt19937 rng(3);
  Database db = make_database(rng, AngularGrid{}, kMedium, 1, 16, 16);
  const auto dir = test::scratch_dir("versions");
  const auto v1 = (dir / "v1.btfdb").string(), v2 = (dir / "v2.btfdb").string();
  write_database(db, v1);

  Database grown = read_database(v1);
  const Material first = grown.materials[0];
  append_rows(grown, rng, Counts{30, 2, 4, 2, 40, 50, 20, 7});
  grown.materials.push_back(random_material(rng, "second", 10, 9, grown.codebooks.p4_index.rows(), Dynamic::HDR));
  write_database(grown, v2);

  const auto b1 = file_bytes(v1), b2 = file_bytes(v2);
  const DatabaseHead h1 = parse_head(b1.data(), b1.size()), h2 = parse_head(b2.data(), b2.size());
  CHECK(h1.version == 1);
  CHECK(h2.version == 2);
  REQUIRE(h2.sections.size() == h1.sections.size() + 9);  // 8 grown code-books + 1 material
  for (size_t i = 0; i < h1.sections.size(); ++i) {
    const SectionEntry &a = h1.sections[i], &b = h2.sections[i];
    CHECK(a.version == 1);
    CHECK(b.version == 1);
    CHECK(a.checksum == b.checksum);
    REQUIRE(a.length == b.length);
    CHECK(std::equal(b1.begin() + long(a.offset), b1.begin() + long(a.offset + a.length), b2.begin() + long(b.offset)));
  }
  const auto delta = sections_since(h2, 1);
  CHECK(delta.size() == 9);
  for (const auto& s : delta) CHECK(s.version == 2);
  CHECK(sections_since(h2, 2).empty());
  CHECK(sections_since(h2, 0).size() == h2.sections.size());

  // Delta download: a client holding v1 fetches the 56-byte header, the head, and only the new
  // sections by range; its own v1 sections fill the rest and rebuild the v2 file byte for byte.
  const uint64_t head_bytes = head_length(b2.data(), kHeaderBytes);
  const DatabaseHead fetched = parse_head(b2.data(), size_t(head_bytes), "v2 head");
  CHECK(fetched.sections == h2.sections);
  std::vector<uint8_t> rebuilt(b2.begin(), b2.begin() + long(head_bytes));
  for (size_t i = 0; i < fetched.sections.size(); ++i) {
    const SectionEntry& s = fetched.sections[i];
    const auto& source = s.version <= 1 ? b1 : b2;  // old sections from the client's own copy
    const uint64_t at = s.version <= 1 ? h1.sections[i].offset : s.offset;
    rebuilt.insert(rebuilt.end(), source.begin() + long(at), source.begin() + long(at + s.length));
  }
  CHECK(rebuilt == b2);

  const Database back = read_database(v2);
  REQUIRE(back.materials.size() == 2);
  CHECK(back.materials[0] == first);
  CHECK(back.versions.size() == 2);
  CHECK(back.versions[0] == h1.versions[0]);
  // The HDR material makes version 2 store P2 scales in 16 bits; version 1 keeps its 8.
  CHECK(back.versions[0].p2_scale.bits == 8);
  CHECK(back.versions[1].p2_scale.bits == 16);
  // The writer is a pure function of the model: the in-memory database published gives the same file.
  publish_version(grown);
  CHECK(back == grown);
  CHECK(serialize_database(grown) == b2);
  // Writing over the previous version (which reuses its stored sections) gives the same bytes, and an
  // unusable "previous" file is ignored.
  std::filesystem::copy_file(v1, dir / "same.btfdb");
  write_database(grown, (dir / "same.btfdb").string());
  CHECK(file_bytes(dir / "same.btfdb") == b2);
  const std::vector<uint8_t> junk(100, 7);
  CHECK(serialize_database(grown, {}, &junk) == b2);
  auto damaged = b1;
  damaged[damaged.size() - 5] ^= 1;
  CHECK(serialize_database(grown, {}, &damaged) == b2);
}

TEST_CASE("a published row may only reference what its version published") {
  std::mt19937 rng(4);
  Database db = make_database(rng, AngularGrid{}, kMedium, 1, 4, 4);
  publish_version(db);
  append_rows(db, rng, Counts{1, 1, 1, 1, 1, 1, 1, 1});
  db.codebooks.p4_index.at(0, 0) = uint32_t(db.codebooks.p3_index.rows() - 1);  // a version-1 row -> a version-2 row
  const auto path = (test::scratch_dir("backref") / "x.btfdb").string();
  CHECK_THROWS_AS(write_database(db, path), InputError);
  CHECK(!std::filesystem::exists(path));
}

TEST_CASE("invalid databases are not written") {
  std::mt19937 rng(5);
  const auto path = (test::scratch_dir("invalid") / "x.btfdb").string();
  Database db = make_database(rng, AngularGrid{}, kMedium, 2, 4, 4);
  db.materials[1].name = db.materials[0].name;
  CHECK_THROWS_AS(write_database(db, path), InputError);
  db = make_database(rng, AngularGrid{}, kMedium, 1, 4, 4);
  db.codebooks.m.at(3, 1) = 999;
  CHECK_THROWS_AS(write_database(db, path), CorruptError);
  db = make_database(rng, AngularGrid{}, kMedium, 1, 4, 4);
  db.codebooks.p3_scale.at(2, 2) = NAN;
  CHECK_THROWS_AS(write_database(db, path), InputError);
  CHECK(!std::filesystem::exists(path));
}

namespace {

// A BTFBASE matrix file: "rows cols min max" then the values.
std::vector<float> read_btfbase(const std::string& file) {
  std::ifstream in(test::testdata_dir() / "btfbase" / "alu" / file);
  REQUIRE(in);
  size_t rows = 0, cols = 0;
  double lo = 0, hi = 0;
  in >> rows >> cols >> lo >> hi;
  std::vector<float> v(rows * cols);
  for (float& x : v) in >> x;
  REQUIRE(in);
  return v;
}

double max_relative_error(const std::vector<float>& v, ValueCoding coding) {
  auto q = v;
  quantize_values(q.data(), q.size(), coding, "test");
  double worst = 0;
  for (size_t i = 0; i < v.size(); ++i)
    if (v[i] != 0) worst = std::max(worst, std::abs(double(q[i]) - v[i]) / std::abs(double(v[i])));
  return worst;
}

}  // namespace

TEST_CASE("scalar quantization error on the real alu database ranges") {
  const ValueCoding log8{ValueCoding::Log, 8}, lin8{ValueCoding::Linear, 8}, log16{ValueCoding::Log, 16},
      lin16{ValueCoding::Linear, 16};
  struct Case {
    const char* file;
    ValueCoding coding;
    double bound;
  };
  // Bounds from the formulas: Linear (max/min - 1) / (2 L); Log ln(max/min) / (2 (L - 1)), plus rounding.
  const Case cases[] = {
      {"all_PDF2Dscale.txt", log8, 0.0040},   {"all_PDF2Dscale.txt", log16, 1.5e-5},
      {"all_PDF3Dscale.txt", log8, 0.0007},   {"all_PDF4Dscale.txt", log8, 0.0001},
      {"alu_PDF6Dscale.txt", log8, 0.0004},   {"all_PDF1Dslice.txt", log8, 0.0060},
      {"all_PDF3Dscale.txt", lin8, 0.0008},   {"all_colors.txt", lin16, 1e-6},
      {"all_PDF1Dslice.txt", lin16, 0.0003},
  };
  for (const Case& c : cases) {
    const double e = max_relative_error(read_btfbase(c.file), c.coding);
    MESSAGE(std::string(c.file) << " mode " << int(c.coding.mode) << " bits " << int(c.coding.bits) << ": max relative error " << e);
    CHECK(e < c.bound);
    CHECK(e < 0.01);
  }
  // On values that fill the P2 range densely, linear 8 bits (the paper's choice) exceeds 1 % near the
  // minimum ((1919/293 - 1) / 510 = 1.09 %), logarithmic 8 bits stays at ln(1919/293) / 508 = 0.37 %.
  std::vector<float> dense;
  for (int i = 0; i <= 20000; ++i) dense.push_back(293.0f + 1626.0f * float(i) / 20000.0f);
  const double linear = max_relative_error(dense, lin8), logarithmic = max_relative_error(dense, log8);
  MESSAGE("dense P2 range: linear 8 bits " << linear << ", log 8 bits " << logarithmic);
  CHECK(linear > 0.0105);
  CHECK(linear < 0.0110);
  CHECK(logarithmic < 0.0038);
}

TEST_CASE("P4 scales keep only the codes their relative error needs, in an ordinary 8-bit field") {
  // P4 scales of a normalized entry span a ratio of about 1.5; dense values over 0.8 .. 1.2.
  std::vector<float> v;
  for (int i = 0; i <= 20000; ++i) v.push_back(0.8f + 0.4f * float(i) / 20000.0f);
  const ValueCoding log8{ValueCoding::Log, 8};
  const Quantizer q = Quantizer::fit(v.data(), v.size(), log8, "test");
  // One code is ln(1.5) / 254 = 0.16 % apart; codes at most 9 apart keep 0.72 % < 0.75 % (10: 0.80 %),
  // and 254 / 9 = 28.2 gaps take 30 levels.
  CHECK(q.levels_for(0.0075) == 30);
  CHECK(q.levels_for(0) == 0);
  CHECK(q.levels_for(1e-5) == 0);  // more levels than 8 bits have: every code
  auto a = v;
  quantize_values(a.data(), a.size(), log8, "test", 0.0075);
  std::vector<float> distinct = a;
  std::sort(distinct.begin(), distinct.end());
  distinct.erase(std::unique(distinct.begin(), distinct.end()), distinct.end());
  CHECK(distinct.size() == 30);
  CHECK(distinct.front() == v.front());  // the ends stay, so a refit gives the same quantizer
  CHECK(distinct.back() == v.back());
  double worst = 0;
  for (size_t i = 0; i < v.size(); ++i) worst = std::max(worst, std::abs(double(a[i]) - v[i]) / double(v[i]));
  MESSAGE("30 of 255 codes: max relative error " << worst);
  CHECK(worst <= 0.0075 * 1.01);
  CHECK(worst > 0.0060);
  // What a reader decodes: the plain 8-bit quantizer maps every such value to itself, and snapping
  // again changes nothing.
  auto b = a, c = a;
  quantize_values(b.data(), b.size(), log8, "test");
  quantize_values(c.data(), c.size(), log8, "test", 0.0075);
  CHECK(b == a);
  CHECK(c == a);
}

TEST_CASE("the default P4 scale error makes the file smaller and stays within its bound") {
  std::mt19937 rng(3);
  Database db = make_database(rng, AngularGrid{}, Counts{200, 5, 20, 6, 300, 320, 120, 400}, 1, 16, 12);
  for (float& s : db.codebooks.p4_scale.data()) s = uniform(rng, 0.8f, 1.2f);
  PackSettings every_code;
  every_code.p4_scale_error = 0;
  const auto coarse = serialize_database(db), fine = serialize_database(db, every_code);
  const double error = PackSettings{}.p4_scale_error;
  REQUIRE(error > 0);
  MESSAGE("P4 scales within " << error << ": " << coarse.size() << " bytes, every code: " << fine.size());
  CHECK(coarse.size() < fine.size());
  const Database back = parse_database(coarse, "memory");
  const auto& was = db.codebooks.p4_scale.data();
  const auto& now = back.codebooks.p4_scale.data();
  REQUIRE(was.size() == now.size());
  for (size_t i = 0; i < was.size(); ++i) CHECK(std::abs(double(now[i]) - was[i]) <= error * 1.01 * double(was[i]));
}

namespace {

template <class T>
Table<T> btfbase_table(const std::string& file, size_t cols) {
  std::ifstream in(test::testdata_dir() / "btfbase" / "alu" / file);
  REQUIRE(in);
  size_t rows = 0, c = 0;
  double lo = 0, hi = 0;
  in >> rows >> c >> lo >> hi;
  REQUIRE(c == cols);
  Table<T> t(cols);
  t.data().resize(rows * cols);
  for (T& x : t.data()) in >> x;
  REQUIRE(in);
  return t;
}

// The real alu database of the original compressor (docs/btfbase-format.md), as the in-memory model.
Database load_alu() {
  Database db;
  db.codebooks = Codebooks(AngularGrid{});
  Codebooks& k = db.codebooks;
  k.p1 = btfbase_table<float>("all_PDF1Dslice.txt", 11);
  k.c = btfbase_table<float>("all_colors.txt", 2);
  k.i1 = btfbase_table<uint32_t>("all_indexAB.txt", 11);
  k.i2 = btfbase_table<uint32_t>("all_PDF2Dcolours.txt", 11);
  k.p2_index = btfbase_table<uint32_t>("all_PDF2Dslices.txt", 11);
  k.p2_scale = btfbase_table<float>("all_PDF2Dscale.txt", 11);
  k.m = btfbase_table<uint32_t>("all_PDF2Dindices.txt", 2);
  k.p3_index = btfbase_table<uint32_t>("all_PDF3Dslices.txt", 7);
  k.p3_scale = btfbase_table<float>("all_PDF3Dscale.txt", 7);
  k.p4_index = btfbase_table<uint32_t>("all_PDF4Dslices.txt", 16);
  k.p4_scale = btfbase_table<float>("all_PDF4Dscale.txt", 16);
  Material m;
  m.name = "alu";
  m.width = m.height = 64;
  m.raw_bytes = 64ull * 64 * 81 * 81 * 3;
  const auto p6 = btfbase_table<uint32_t>("alu_PDF6Dslices.txt", 64);
  for (uint32_t i : p6.data()) m.p6_index.push_back(int32_t(i) - 1);
  m.p6_scale = btfbase_table<float>("alu_PDF6Dscale.txt", 64).data();
  db.materials.push_back(m);
  return db;
}

}  // namespace

TEST_CASE("the real alu database: lossless import and default packing sizes") {
  const Database alu = load_alu();
  alu.validate();
  const auto lossless = serialize_database(alu, PackSettings::lossless());
  const Database back = parse_database(lossless);
  CHECK(back.codebooks == alu.codebooks);
  CHECK(back.materials == alu.materials);
  const auto packed = serialize_database(alu);
  Database quantized = alu;
  publish_version(quantized);
  CHECK(parse_database(packed) == quantized);
  const auto unentropy = serialize_database(alu, without_zstd());
  const auto zstd = serialize_database(alu, zstd_only());
  CHECK(parse_database(zstd).codebooks == quantized.codebooks);
  const DatabaseHead head = parse_head(packed.data(), packed.size()), zhead = parse_head(zstd.data(), zstd.size());
  int zstd_sections = 0, modelled_sections = 0;
  for (const auto& s : zhead.sections) zstd_sections += s.encoding == 1 ? 1 : 0;
  for (const auto& s : head.sections) modelled_sections += s.encoding == 2 ? 1 : 0;
  CHECK(zstd_sections >= 5);  // zstd wins on most sections of real data
  CHECK(modelled_sections >= 5);  // and the range coder beats it on most
  CHECK(zstd.size() < unentropy.size());
  // The acceptance figure of the entropy coding: at least 20 % more ratio than raw packed (measured 53 %).
  CHECK(double(unentropy.size()) / double(packed.size()) > 1.2);
  CHECK(packed.size() < zstd.size());
  // The original's own quantizer wrote 80,460 bytes (quantreport.txt: 8-bit linear everything, compact
  // indices); ours stores C in 16 bits and adds the head and checksums, and must stay close.
  MESSAGE("alu: raw 32-bit " << raw_float_bytes(alu) << " bytes, lossless " << lossless.size() << ", default "
                             << unentropy.size() << " packed, " << packed.size()
                             << " packed + zstd, " << packed.size()
                             << " packed + range coder (original compressor: 80460); measured BTF "
                             << alu.materials[0].raw_bytes << " bytes -> 1:"
                             << double(alu.materials[0].raw_bytes) / double(packed.size()));
  CHECK(unentropy.size() < 81000);
  CHECK(unentropy.size() == expected_size(alu, 8, 16, 8));

  // Corruption inside coded sections is caught too (checksum first; the decoder never sees it).
  std::mt19937 rng(9);
  for (int t = 0; t < 300; ++t) {
    auto bad = packed;
    bad[std::uniform_int_distribution<size_t>(0, bad.size() - 1)(rng)] ^= uint8_t(1 + pick(rng, 255));
    CHECK_THROWS_AS(parse_database(bad, "alu"), CorruptError);
  }
}

TEST_CASE("every flipped byte and every truncation of a small file is a CorruptError") {
  // Once with zstd alone (encoding 1) and once with the range coder alone (encoding 2) on the
  // compressible section.
  for (const bool range_coding : {false, true}) {
  CAPTURE(range_coding);
  PackSettings settings;
  settings.range_coding = range_coding;
  if (range_coding) settings.zstd_level = 0;
  std::mt19937 rng(6);
  AngularGrid g;
  g.n_beta = 3;
  g.n_alpha = 2;
  g.n_theta_v = 2;
  g.n_phi_v = 2;
  Database db = make_database(rng, g, Counts{3, 2, 2, 2, 3, 3, 2, 2}, 1, 2, 2);
  publish_version(db);
  append_rows(db, rng, Counts{1, 0, 1, 0, 1, 1, 1, 1});
  db.materials.push_back(random_material(rng, "b", 2, 1, db.codebooks.p4_index.rows()));
  Material flat = random_material(rng, "flat", 24, 24, db.codebooks.p4_index.rows());
  std::fill(flat.p6_index.begin(), flat.p6_index.end(), 1);
  std::fill(flat.p6_scale.begin(), flat.p6_scale.end(), 1.0f);
  db.materials.push_back(flat);  // compresses: its section is stored coded (encoding 1 or 2)
  const auto good = serialize_database(db, settings);
  REQUIRE(good.size() < 2000);
  const DatabaseHead head = parse_head(good.data(), good.size());
  CHECK(head.sections.back().encoding == (range_coding ? 2 : 1));
  CHECK(head.sections.front().encoding == 0);
  MESSAGE("small file: " << good.size() << " bytes, every position flipped and truncated");
  CHECK_NOTHROW(parse_database(good));
  int corrupt = 0;
  for (size_t i = 0; i < good.size(); ++i)
    for (uint8_t mask : {uint8_t(0x01), uint8_t(0x80), uint8_t(0xFF)}) {
      auto bad = good;
      bad[i] ^= mask;
      try {
        parse_database(bad, "flip");
        FAIL("flipped byte " << i << " was accepted");
      } catch (const CorruptError&) {
        ++corrupt;
      }
    }
  CHECK(corrupt == int(3 * good.size()));
  for (size_t n = 0; n < good.size(); ++n) {
    std::vector<uint8_t> cut(good.begin(), good.begin() + long(n));
    CHECK_THROWS_AS(parse_database(cut, "cut"), CorruptError);
  }
  auto longer = good;
  longer.push_back(0);
  CHECK_THROWS_AS(parse_database(longer, "long"), CorruptError);
  }
}

TEST_CASE("random corruption of a larger file is always detected, with a message naming the section") {
  std::mt19937 rng(8);
  Database db = make_database(rng, AngularGrid{}, kMedium, 2, 16, 16);
  const auto good = serialize_database(db);
  const DatabaseHead h = parse_head(good.data(), good.size());
  std::uniform_int_distribution<size_t> pos(0, good.size() - 1);
  for (int t = 0; t < 2000; ++t) {
    auto bad = good;
    const size_t i = pos(rng);
    bad[i] ^= uint8_t(1 + pick(rng, 255));
    CHECK_THROWS_AS(parse_database(bad, "big"), CorruptError);
  }
  // A flip inside the P6 data of the second material names that section.
  const SectionEntry& mat = h.sections.back();
  auto bad = good;
  bad[mat.offset + mat.length - 3] ^= 0x10;
  try {
    parse_database(bad, "big.btfdb");
    FAIL("accepted");
  } catch (const CorruptError& e) {
    const std::string msg = e.what();
    CHECK(msg.find("big.btfdb") != std::string::npos);
    CHECK(msg.find("material 'mat1'") != std::string::npos);
    CHECK(msg.find("checksum") != std::string::npos);
  }
  for (size_t n : {size_t(0), size_t(7), size_t(55), size_t(h.head_length - 1), size_t(h.head_length + 100), good.size() - 1})
    CHECK_THROWS_AS(parse_database(std::vector<uint8_t>(good.begin(), good.begin() + long(n)), "cut"), CorruptError);
}

TEST_CASE("a file that is not a database gets a clear error") {
  const auto dir = test::scratch_dir("notdb");
  const auto text = (dir / "notes.txt").string();
  std::ofstream(text) << "hello, this is not a database\n";
  CHECK(!is_database_file(text));
  try {
    read_database(text);
    FAIL("accepted");
  } catch (const CorruptError& e) {
    CHECK(std::string(e.what()).find("not a btfvq database") != std::string::npos);
    CHECK(std::string(e.what()).find("notes.txt") != std::string::npos);
  }
  CHECK_THROWS_AS(read_database((dir / "missing.btfdb").string()), InputError);
  CHECK_THROWS_AS(read_database(dir.string()), InputError);  // a directory
  std::ofstream(dir / "empty.btfdb").flush();
  CHECK_THROWS_AS(read_database((dir / "empty.btfdb").string()), CorruptError);
  CHECK(!is_database_file((dir / "missing.btfdb").string()));
}

namespace {

void put_u64(std::vector<uint8_t>& b, size_t at, uint64_t v) {
  for (int i = 0; i < 8; ++i) b[at + size_t(i)] = uint8_t(v >> (8 * i));
}

}  // namespace

TEST_CASE("changed bytes with recomputed checksums are decoded or rejected, never a crash") {
  // What a crafted file could do: every byte changed, then the section and head CRCs made valid again.
  // The reader must either decode a consistent database or throw CorruptError (no other exception).
  std::mt19937 rng(10);
  AngularGrid g;
  g.n_beta = 3;
  g.n_alpha = 2;
  g.n_theta_v = 2;
  g.n_phi_v = 2;
  Database db = make_database(rng, g, Counts{3, 2, 2, 2, 3, 3, 2, 2}, 1, 3, 2);
  publish_version(db);
  append_rows(db, rng, Counts{1, 1, 1, 1, 1, 1, 1, 1});
  Material flat = random_material(rng, "flat", 24, 24, db.codebooks.p4_index.rows());
  std::fill(flat.p6_index.begin(), flat.p6_index.end(), 2);
  db.materials.push_back(flat);
  PackSettings range_coder_only;
  range_coder_only.zstd_level = 0;
  const auto good = serialize_database(db, range_coder_only);
  const DatabaseHead h = parse_head(good.data(), good.size());
  REQUIRE(h.sections.back().encoding == 2);  // the range coder's decoder faces the crafted bytes
  // Where each table entry's checksum field lives.
  std::vector<size_t> crc_at;
  size_t at = kHeaderBytes + 52 * h.versions.size();
  for (const auto& s : h.sections) {
    crc_at.push_back(at + 32);
    at += 44 + s.material.size();
  }
  const size_t head_crc = size_t(h.head_length) - 8;
  int decoded = 0, rejected = 0;
  for (size_t i = 0; i < good.size(); ++i) {
    if (i >= head_crc && i < head_crc + 8) continue;
    for (uint8_t mask : {uint8_t(0x01), uint8_t(0x10), uint8_t(0xFF)}) {
      auto bad = good;
      bad[i] ^= mask;
      for (size_t s = 0; s < h.sections.size(); ++s) {
        const auto& e = h.sections[s];
        if (i >= e.offset && i < e.offset + e.length) put_u64(bad, crc_at[s], crc64(bad.data() + e.offset, size_t(e.length)));
      }
      put_u64(bad, head_crc, crc64(bad.data(), head_crc));
      try {
        const Database d = parse_database(bad, "crafted");
        d.validate();
        ++decoded;
      } catch (const CorruptError&) {
        ++rejected;
      }
    }
  }
  MESSAGE("crafted changes: " << decoded << " decoded consistently, " << rejected << " rejected");
  CHECK(rejected > decoded);
}

TEST_CASE("a file written before encoding 2 existed still reads, rewrites byte for byte and grows") {
  // tests/golden/v1_zstd_two_versions.btfdb: written by the zstd-only writer (encodings 0 and 1,
  // version records with the range coding byte 0): btfvq compress of synth wood 8 x 8, then foil 6 x 6.
  const auto golden = test::source_dir() / "tests" / "golden" / "v1_zstd_two_versions.btfdb";
  const auto old_bytes = file_bytes(golden);
  REQUIRE(old_bytes.size() == 11801);
  const Database db = read_database(golden.string());
  REQUIRE(db.materials.size() == 2);
  CHECK(db.materials[0].name == "wood");
  CHECK(db.materials[1].name == "foil");
  REQUIRE(db.versions.size() == 2);
  for (const VersionMark& v : db.versions) CHECK(v.range_coding == 0);
  const DatabaseHead old_head = parse_head(old_bytes.data(), old_bytes.size());
  int zstd_sections = 0;
  for (const auto& s : old_head.sections) {
    CHECK(s.encoding <= 1);
    zstd_sections += s.encoding == 1;
  }
  CHECK(zstd_sections >= 5);
  // Rewriting keeps the old encodings (the records say zstd only), with or without the old file.
  CHECK(serialize_database(db, {}, &old_bytes) == old_bytes);
  CHECK(serialize_database(db) == old_bytes);
  // A new version is written with the range coder; the old sections stay as they were.
  Database grown = db;
  Material copy = grown.materials[0];
  copy.name = "wood again";
  grown.materials.push_back(copy);
  const auto new_bytes = serialize_database(grown, {}, &old_bytes);
  const DatabaseHead new_head = parse_head(new_bytes.data(), new_bytes.size());
  REQUIRE(new_head.sections.size() == old_head.sections.size() + 1);
  for (size_t i = 0; i < old_head.sections.size(); ++i) {
    const SectionEntry &a = old_head.sections[i], &b = new_head.sections[i];
    REQUIRE(a.length == b.length);
    CHECK(a.checksum == b.checksum);
    CHECK(std::equal(old_bytes.begin() + long(a.offset), old_bytes.begin() + long(a.offset + a.length),
                     new_bytes.begin() + long(b.offset)));
  }
  CHECK(new_head.versions.back().range_coding == 1);
  CHECK(new_head.sections.back().encoding == 2);
  const Database back = parse_database(new_bytes);
  CHECK(back.materials[2].p6_index == db.materials[0].p6_index);
  CHECK(back.materials[2].p6_scale == db.materials[0].p6_scale);
  CHECK(back.codebooks == db.codebooks);
}
