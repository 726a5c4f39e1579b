#include <doctest/doctest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "pipeline/io/btfbase.h"
#include "pipeline/decode/decoder.h"
#include <btfvq/error.h>
#include "support/test_paths.h"

using namespace btfvq;
namespace fs = std::filesystem;

namespace {

fs::path alu_dir() { return test::testdata_dir() / "btfbase" / "alu"; }
fs::path proposte_dir() { return test::testdata_dir() / "btfbase" / "proposte"; }

const Database& alu() {
  static const Database db = import_btfbase(alu_dir().string());
  return db;
}

void spit(const fs::path& p, const std::string& text) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out << text;
}

// A writable copy of alu in scratch space, for damaging.
fs::path alu_copy(const std::string& name) {
  const fs::path dir = test::scratch_dir(name);
  for (const auto& e : fs::directory_iterator(alu_dir())) {
    fs::copy_file(e.path(), dir / e.path().filename());
    fs::permissions(dir / e.path().filename(), fs::perms::owner_read | fs::perms::owner_write);
  }
  return dir;
}

// Replaces the value at data row `row`, column `col` of a matrix file.
void set_value(const fs::path& file, size_t row, size_t col, const std::string& value) {
  std::istringstream in(test::file_bytes(file));
  std::string out, line;
  for (size_t l = 0; std::getline(in, line); ++l) {
    if (l == row + 1) {
      std::istringstream ls(line);
      std::string tok, rebuilt;
      for (size_t c = 0; ls >> tok; ++c) rebuilt += (c == col ? value : tok) + " ";
      line = rebuilt;
    }
    out += line + "\n";
  }
  spit(file, out);
}

template <class E>
std::string error_of(const fs::path& dir) {
  try {
    import_btfbase(dir.string());
  } catch (const E& e) {
    return e.what();
  }
  FAIL("import of " << dir << " did not throw the expected error");
  return {};
}

// Database has no operator== of its own (pipeline/codebook.h): compare what it consists of.
bool same(const Database& a, const Database& b) { return a.codebooks == b.codebooks && a.materials == b.materials; }

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

}  // namespace

TEST_CASE("alu imports with the sizes of docs/btfbase-format.md and quantreport.txt") {
  const Database& db = alu();
  const Codebooks& k = db.codebooks;
  CHECK(k.grid.n_beta == 11);
  CHECK(k.grid.n_alpha == 11);
  CHECK(k.grid.n_theta_v == 7);
  CHECK(k.grid.n_phi_v == 16);
  // quantreport.txt: 1D PDF 1381, colours 2, index slices 5, 2D PDF Lums 1645, 2D PDF ABs 4,
  // 2D PDFs 1723, 3D PDFs 539, 4D PDFs 34, 6D PDFs 4096.
  CHECK(k.p1.rows() == 1381);
  CHECK(k.p1.cols() == 11);
  CHECK(k.c.rows() == 2);
  CHECK(k.i1.rows() == 5);
  CHECK(k.p2_index.rows() == 1645);
  CHECK(k.p2_scale.rows() == 1645);
  CHECK(k.i2.rows() == 4);
  CHECK(k.m.rows() == 1723);
  CHECK(k.p3_index.rows() == 539);
  CHECK(k.p3_scale.rows() == 539);
  CHECK(k.p4_index.rows() == 34);
  CHECK(k.p4_scale.cols() == 16);
  REQUIRE(db.materials.size() == 1);
  const Material& m = db.materials[0];
  CHECK(m.name == "alu");
  CHECK(m.width == 64);
  CHECK(m.height == 64);
  CHECK(m.dynamic == Dynamic::LDR);
  CHECK(m.raw_bytes == 80621568);  // quantreport: "size data uncompressed = 80621568"
  CHECK(m.p6_index.size() == 4096);
  // Values read straight from the files: first P1 row starts 0.117859 0.088002; C row 1 is
  // (115.057739, 128.890747); P6 row 0 starts "12 12 18" (1-based) and its scale 0.999...
  CHECK(k.p1.at(0, 0) == 0.117859f);
  CHECK(k.p1.at(0, 1) == 0.088002f);
  CHECK(k.c.at(1, 0) == 115.057739f);
  CHECK(k.c.at(1, 1) == 128.890747f);
  CHECK(k.p3_scale.at(1, 1) == 0.989172f);
  CHECK(m.p6_index[0] == 11);
  CHECK(m.p6_index[1] == 11);
  CHECK(m.p6_index[2] == 17);
  CHECK(k.i2.at(1, 7) == 2);
}

TEST_CASE("export then import reproduces alu exactly, and decodes identically") {
  const fs::path out = test::scratch_dir("roundtrip") / "alu-export";
  export_btfbase(alu(), out.string());
  for (const char* f : {"all_materialInfo.txt", "all_PDF1Dslice.txt", "all_colors.txt", "all_indexAB.txt",
                        "all_PDF2Dcolours.txt", "all_PDF2Dslices.txt", "all_PDF2Dscale.txt", "all_PDF2Dindices.txt",
                        "all_PDF3Dslices.txt", "all_PDF3Dscale.txt", "all_PDF4Dslices.txt", "all_PDF4Dscale.txt",
                        "alu_PDF6Dslices.txt", "alu_PDF6Dscale.txt", "alu_materialInfo.txt"})
    CHECK_MESSAGE(fs::exists(out / f), f);
  // P6 is written 1-based, like the original.
  CHECK(test::file_bytes(out / "alu_PDF6Dslices.txt").substr(0, 20) == "64 64 1 34\n12 12 18 ");
  const Database again = import_btfbase(out.string());
  CHECK(same(again, alu()));

  // Exporting the re-import writes byte-identical files (the writer is deterministic).
  const fs::path out2 = test::scratch_dir("roundtrip2") / "alu-export";
  export_btfbase(again, out2.string());
  for (const auto& e : fs::directory_iterator(out)) CHECK(test::file_bytes(e.path()) == test::file_bytes(out2 / e.path().filename()));

  const Decoder a(alu()), b(again);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> theta(0, 90), phi(0, 360);
  std::uniform_int_distribution<int> coord(0, 63);
  for (int i = 0; i < 20000; ++i) {
    const int x = coord(rng), y = coord(rng);
    const Direction l{theta(rng), phi(rng)}, v{theta(rng), phi(rng)};
    const Rgb p = a.evaluate(0, x, y, l, v), q = b.evaluate(0, x, y, l, v);
    REQUIRE(p.r == q.r);
    REQUIRE(p.g == q.g);
    REQUIRE(p.b == q.b);
  }
}

TEST_CASE("an empty database and one with two materials (one HDR) round-trip") {
  const fs::path parent = test::scratch_dir("shapes");
  Database empty;
  empty.codebooks = Codebooks(AngularGrid{});
  export_btfbase(empty, (parent / "empty").string());
  const Database e = import_btfbase((parent / "empty").string());
  CHECK(same(e, empty));

  Database two = alu();
  Material hdr = two.materials[0];
  hdr.name = "alu_hdr";
  hdr.dynamic = Dynamic::HDR;
  hdr.raw_bytes = hdr.raw_bytes * 3 / 2;  // 12 bits per channel, what the import recomputes
  hdr.p6_index[5] = -1;                   // an uncompressed texel: stored as 0
  two.materials.push_back(hdr);
  export_btfbase(two, (parent / "two").string());
  const Database t = import_btfbase((parent / "two").string());
  CHECK(same(t, two));
  CHECK(t.materials[1].dynamic == Dynamic::HDR);
  CHECK(t.materials[1].p6_index[5] == -1);
}

TEST_CASE("export replaces an existing directory and never leaves a half-written one") {
  const fs::path parent = test::scratch_dir("atomic");
  const fs::path out = parent / "db";
  fs::create_directories(out);
  spit(out / "stale.txt", "old");
  export_btfbase(alu(), out.string());
  CHECK_FALSE(fs::exists(out / "stale.txt"));
  CHECK(same(import_btfbase(out.string()), alu()));

  // A database with a bad index is refused before anything is written; the old directory stays.
  Database bad = alu();
  bad.codebooks.p3_index.at(17, 3) = 99999;
  CHECK_THROWS_AS(export_btfbase(bad, out.string()), CorruptError);
  CHECK_THROWS_AS(export_btfbase(bad, (parent / "fresh").string()), CorruptError);
  CHECK_FALSE(fs::exists(parent / "fresh"));
  CHECK(same(import_btfbase(out.string()), alu()));
  Database badname = alu();
  badname.materials[0].name = "two words";
  CHECK_THROWS_AS(export_btfbase(badname, (parent / "fresh").string()), InputError);
  size_t entries = 0;
  for (const auto& e : fs::directory_iterator(parent)) {
    (void)e;
    ++entries;
  }
  CHECK(entries == 1);  // only "db": no temporary or backup directories left behind
}

TEST_CASE("an out-of-range index in a P3 file names the file, row and target") {
  const fs::path dir = alu_copy("bad-p3");
  set_value(dir / "all_PDF3Dslices.txt", 17, 3, "1723");
  const std::string msg = error_of<CorruptError>(dir);
  CHECK_MESSAGE(contains(msg, "all_PDF3Dslices.txt row 17"), msg);
  CHECK_MESSAGE(contains(msg, "index 1723 >= 1723 entries of all_PDF2Dindices.txt"), msg);
}

TEST_CASE("an out-of-range P6 index and a negative index are refused") {
  const fs::path dir = alu_copy("bad-p6");
  set_value(dir / "alu_PDF6Dslices.txt", 5, 9, "35");
  const std::string msg = error_of<CorruptError>(dir);
  CHECK_MESSAGE(contains(msg, "alu_PDF6Dslices.txt row 5"), msg);
  CHECK_MESSAGE(contains(msg, "all_PDF4Dslices.txt"), msg);

  const fs::path dir2 = alu_copy("negative");
  set_value(dir2 / "all_PDF2Dindices.txt", 3, 1, "-1");
  const std::string msg2 = error_of<CorruptError>(dir2);
  CHECK_MESSAGE(contains(msg2, "all_PDF2Dindices.txt row 3"), msg2);
}

TEST_CASE("a truncated matrix file, a short row and a non-numeric token name the file") {
  const fs::path dir = alu_copy("truncated");
  const std::string text = test::file_bytes(dir / "all_PDF2Dscale.txt");
  spit(dir / "all_PDF2Dscale.txt", text.substr(0, text.size() / 2));
  const std::string msg = error_of<CorruptError>(dir);
  CHECK_MESSAGE(contains(msg, "all_PDF2Dscale.txt"), msg);
  CHECK_MESSAGE(contains(msg, "row"), msg);

  const fs::path dir2 = alu_copy("short-row");
  set_value(dir2 / "all_PDF1Dslice.txt", 40, 10, "");
  const std::string msg2 = error_of<CorruptError>(dir2);
  CHECK_MESSAGE(contains(msg2, "all_PDF1Dslice.txt row 40"), msg2);

  const fs::path dir3 = alu_copy("token");
  set_value(dir3 / "all_PDF4Dscale.txt", 2, 2, "1.0x");
  const std::string msg3 = error_of<CorruptError>(dir3);
  CHECK_MESSAGE(contains(msg3, "all_PDF4Dscale.txt row 2"), msg3);
  CHECK_MESSAGE(contains(msg3, "1.0x"), msg3);

  const fs::path dir4 = alu_copy("header");
  set_value(dir4 / "all_PDF3Dscale.txt", size_t(-1), 0, "540");  // header claims one row more
  const std::string msg4 = error_of<CorruptError>(dir4);
  CHECK_MESSAGE(contains(msg4, "all_PDF3Dscale.txt"), msg4);
}

TEST_CASE("a missing file or directory is an InputError naming it") {
  const fs::path dir = alu_copy("missing");
  fs::remove(dir / "all_colors.txt");
  const std::string msg = error_of<InputError>(dir);
  CHECK_MESSAGE(contains(msg, "all_colors.txt"), msg);

  const fs::path dir2 = alu_copy("missing-p6");
  fs::remove(dir2 / "alu_PDF6Dscale.txt");
  const std::string msg2 = error_of<InputError>(dir2);
  CHECK_MESSAGE(contains(msg2, "alu_PDF6Dscale.txt"), msg2);

  const std::string msg3 = error_of<InputError>(dir2 / "nope");
  CHECK_MESSAGE(contains(msg3, "nope"), msg3);
}

TEST_CASE("a code-book size in all_materialInfo.txt that disagrees with its file is refused") {
  const fs::path dir = alu_copy("sizes");
  std::string info = test::file_bytes(dir / "all_materialInfo.txt");
  const auto at = info.find("1381 2 5 1723");
  REQUIRE(at != std::string::npos);
  info.replace(at, 4, "1380");
  spit(dir / "all_materialInfo.txt", info);
  const std::string msg = error_of<CorruptError>(dir);
  CHECK_MESSAGE(contains(msg, "all_materialInfo.txt line 13"), msg);
  CHECK_MESSAGE(contains(msg, "all_PDF1Dslice.txt"), msg);
}

TEST_CASE("a material name that would leave the directory is refused") {
  const fs::path dir = alu_copy("name");
  std::string info = test::file_bytes(dir / "all_materialInfo.txt");
  const auto at = info.rfind("alu ./indata");
  REQUIRE(at != std::string::npos);
  info.replace(at, 3, "../x");
  spit(dir / "all_materialInfo.txt", info);
  const std::string msg = error_of<CorruptError>(dir);
  CHECK_MESSAGE(contains(msg, "all_materialInfo.txt line 15"), msg);
}

TEST_CASE("proposte (8 MB of text) imports quickly") {
  const auto start = std::chrono::steady_clock::now();
  const Database db = import_btfbase(proposte_dir().string());
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  MESSAGE("proposte import: " << seconds << " s");
  const Codebooks& k = db.codebooks;
  CHECK(k.p1.rows() == 5889);
  CHECK(k.c.rows() == 11);
  CHECK(k.i1.rows() == 6660);
  CHECK(k.m.rows() == 30919);
  CHECK(k.p2_index.rows() == 26669);
  CHECK(k.i2.rows() == 9965);
  CHECK(k.p3_index.rows() == 12503);
  CHECK(k.p4_index.rows() == 786);
  REQUIRE(db.materials.size() == 1);
  CHECK(db.materials[0].width == 256);
  CHECK(db.materials[0].height == 256);
  CHECK(db.materials[0].raw_bytes == uint64_t(256) * 256 * 81 * 81 * 3);
  CHECK(seconds < 10.0);  // wall time on a loaded 2-core machine; about a second of CPU
}
