// The interop commands as a user runs them: import the original databases, render the known values.
#include <doctest/doctest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>

#include "pipeline/io/btfbase.h"
#include "pipeline/format/database.h"
#include "pipeline/decode/reconstruct.h"
#include "support/test_paths.h"

using namespace btfvq;
namespace fs = std::filesystem;

namespace {

std::string btfvq_cli() { return (test::bin_dir() / "btfvq").string(); }

struct Known {
  const char* material;
  int x, y;
  const char* light;
  const char* view;
  double r, g, b;
};

// docs/btfbase-format.md's table, from an independent re-implementation of the original decoder.
const Known kKnown[] = {
    {"alu", 0, 0, "0,0", "0,0", 261.51, 263.54, 259.34},
    {"alu", 10, 20, "60,90", "0,0", 62.66, 64.64, 60.54},
    {"alu", 33, 7, "45,120", "30,60", 61.33, 63.31, 59.21},
    {"alu", 5, 40, "75,345", "75,15", 19.86, 21.78, 17.81},
    {"alu", 63, 63, "15,300", "60,240", 76.56, 78.53, 74.45},
    {"proposte", 0, 0, "0,0", "0,0", 233.31, 209.99, 175.31},
    {"proposte", 10, 20, "60,90", "0,0", 141.91, 127.94, 108.17},
    {"proposte", 33, 7, "45,120", "30,60", 205.27, 192.56, 174.63},
    {"proposte", 5, 40, "75,345", "75,15", 179.94, 167.17, 149.14},
    {"proposte", 63, 63, "15,300", "60,240", 227.56, 199.34, 159.10},
};

}  // namespace

TEST_CASE("import-btfbase then render --texel reproduces docs/btfbase-format.md's decoded values to 0.05") {
  const fs::path dir = test::scratch_dir("cli-interop");
  for (const char* name : {"alu", "proposte"}) {
    const fs::path db = dir / (std::string(name) + ".btfdb");
    std::string out;
    REQUIRE(test::run_command(btfvq_cli() + " import-btfbase " + (test::testdata_dir() / "btfbase" / name).string() +
                                  " --db " + db.string(),
                              &out) == 0);
    for (const Known& k : kKnown) {
      if (std::string(k.material) != name) continue;
      const fs::path png = dir / "r.png";
      REQUIRE(test::run_command(btfvq_cli() + " render " + db.string() + " --material " + name + " --light " + k.light +
                                    " --view " + k.view + " --texel " + std::to_string(k.x) + "," + std::to_string(k.y) +
                                    " --out " + png.string(),
                                &out) == 0);
      double r = 0, g = 0, b = 0;
      const auto at = out.find("R ");
      REQUIRE(at != std::string::npos);
      REQUIRE(std::sscanf(out.c_str() + at, "R %lf G %lf B %lf", &r, &g, &b) == 3);
      CHECK(std::abs(r - k.r) <= 0.05);
      CHECK(std::abs(g - k.g) <= 0.05);
      CHECK(std::abs(b - k.b) <= 0.05);
      CHECK(fs::file_size(png) > 1000);
    }
  }
}

TEST_CASE("an imported database decodes exactly like the text database it came from") {
  const fs::path dir = test::scratch_dir("cli-interop-exact");
  const Database text = import_btfbase((test::testdata_dir() / "btfbase" / "alu").string());
  const fs::path db = dir / "alu.btfdb";
  REQUIRE(test::run_command(btfvq_cli() + " import-btfbase " + (test::testdata_dir() / "btfbase" / "alu").string() +
                            " --db " + db.string()) == 0);
  const Database file = read_database(db.string());
  CHECK(file.codebooks == text.codebooks);
  CHECK(file.materials == text.materials);
  const auto a = decode_image(text, "alu", {45, 120}, {30, 60});
  const auto b = decode_image(file, "alu", {45, 120}, {30, 60});
  CHECK(a == b);
}

TEST_CASE("export-btfbase of an imported database re-imports identically") {
  const fs::path dir = test::scratch_dir("cli-interop-export");
  const fs::path db = dir / "alu.btfdb", out = dir / "exported";
  REQUIRE(test::run_command(btfvq_cli() + " import-btfbase " + (test::testdata_dir() / "btfbase" / "alu").string() +
                            " --db " + db.string()) == 0);
  REQUIRE(test::run_command(btfvq_cli() + " export-btfbase " + db.string() + " --out " + out.string()) == 0);
  const Database again = import_btfbase(out.string());
  const Database file = read_database(db.string());
  CHECK(again.codebooks == file.codebooks);
  CHECK(again.materials == file.materials);
}

TEST_CASE("import of a damaged copy fails, names the file and writes nothing") {
  const fs::path dir = test::scratch_dir("cli-interop-damaged");
  const fs::path copy = dir / "alu";
  fs::copy(test::testdata_dir() / "btfbase" / "alu", copy);
  for (auto& e : fs::directory_iterator(copy)) fs::permissions(e.path(), fs::perms::owner_write, fs::perm_options::add);
  fs::remove(copy / "all_PDF3Dscale.txt");
  const fs::path db = dir / "out.btfdb";
  std::string out;
  CHECK(test::run_command(btfvq_cli() + " import-btfbase " + copy.string() + " --db " + db.string(), &out) != 0);
  CHECK(out.find("all_PDF3Dscale.txt") != std::string::npos);
  CHECK_FALSE(fs::exists(db));
}
