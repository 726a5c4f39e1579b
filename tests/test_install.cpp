// `make install` as a renderer team uses it: the public headers are exactly include/btfvq/, and a
// program outside the tree builds against <btfvq/renderer_api.h> with only the install prefix on its
// include and library paths, then decodes a known value of the original authors' alu database.
#include <doctest/doctest.h>

#include <filesystem>
#include <fstream>
#include <set>

#include "support/test_paths.h"

namespace fs = std::filesystem;
using namespace btfvq;

namespace {

std::set<std::string> files_below(const fs::path& dir) {
  std::set<std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.is_regular_file()) out.insert(fs::relative(e.path(), dir).string());
  return out;
}

}  // namespace

TEST_CASE("the install holds exactly the public headers, and a program outside the tree builds against them") {
  const fs::path prefix = test::scratch_dir("install") / "prefix";
  std::string log;
  const std::string build_dir = test::bin_dir().parent_path().string();
  REQUIRE_MESSAGE(test::run_command("cmake --install '" + build_dir + "' --prefix '" + prefix.string() + "'", &log) == 0,
                  log);
  CHECK(files_below(prefix / "include") == files_below(test::source_dir() / "include"));
  CHECK(fs::exists(prefix / "lib" / "libbtfvq.so"));

  const fs::path program = prefix.parent_path() / "renderer.cpp";
  std::ofstream(program) << R"(#include <btfvq/renderer_api.h>
#include <btfvq/error.h>
#include <cstdio>
int main(int argc, char** argv) {
  try {
    const btfvq::BtfDatabase db = btfvq::BtfDatabase::open(argv[1]);
    const btfvq::BtfMaterial alu = db.material("alu");
    // docs/btfbase-format.md, known values: alu texel (33, 7), light (45, 120), view (30, 60).
    const btfvq::Rgb c = alu.evaluate((33 + 0.5) / 64, (7 + 0.5) / 64, btfvq::Direction{45, 120}, btfvq::Direction{30, 60});
    std::printf("%.2f %.2f %.2f\n", c.r, c.g, c.b);
    db.material("no such material");
  } catch (const btfvq::NotFoundError& e) {
    std::printf("not found: %s\n", e.what());
    return 0;
  }
  return 1;
}
)";
  const fs::path exe = prefix.parent_path() / "renderer";
  const std::string compile = "c++ -std=c++17 -I'" + (prefix / "include").string() + "' '" + program.string() +
                              "' -o '" + exe.string() + "' -L'" + (prefix / "lib").string() + "' -lbtfvq -Wl,-rpath,'" +
                              (prefix / "lib").string() + "'";
  REQUIRE_MESSAGE(test::run_command(compile, &log) == 0, log);
  REQUIRE(test::run_command("'" + exe.string() + "' '" + (test::testdata_dir() / "btfbase" / "alu").string() + "'", &log) == 0);
  float r = 0, g = 0, b = 0;
  REQUIRE(std::sscanf(log.c_str(), "%f %f %f", &r, &g, &b) == 3);
  CHECK(r == doctest::Approx(61.33).epsilon(0.05 / 61.33));
  CHECK(g == doctest::Approx(63.31).epsilon(0.05 / 63.31));
  CHECK(b == doctest::Approx(59.21).epsilon(0.05 / 59.21));
  CHECK(log.find("not found:") != std::string::npos);
}

TEST_CASE("the install holds the Python module, importable by Debian's python3 from the install alone") {
  const fs::path build_python = test::bin_dir().parent_path() / "python";
  if (!fs::exists(build_python)) return;  // configured with -DBTFVQ_PYTHON=OFF
  const fs::path prefix = test::scratch_dir("install-python") / "prefix";
  std::string log;
  REQUIRE_MESSAGE(test::run_command("cmake --install '" + test::bin_dir().parent_path().string() + "' --prefix '" +
                                        prefix.string() + "'", &log) == 0, log);
  fs::path module_dir;
  for (const std::string& f : files_below(prefix / "lib"))
    if (f.find("dist-packages/btfvq.") != std::string::npos) module_dir = prefix / "lib" / fs::path(f).parent_path();
  REQUIRE_MESSAGE(!module_dir.empty(), "no btfvq module below " << (prefix / "lib").string());
  // lib/python3.X/dist-packages: the prefix /usr/local gives a folder in Debian's sys.path.
  CHECK(module_dir.parent_path().filename().string().rfind("python3.", 0) == 0);
  const std::string cmd = "cd / && PYTHONPATH='" + module_dir.string() + "' /usr/bin/python3 -c \"import btfvq; "
                          "m = btfvq.open('" + (test::testdata_dir() / "btfbase" / "alu").string() +
                          "')['alu']; print(btfvq.__file__); print(m.width, m.height)\"";
  REQUIRE_MESSAGE(test::run_command(cmd, &log) == 0, log);
  CHECK(log.find(module_dir.string()) != std::string::npos);
  CHECK(log.find("64 64") != std::string::npos);
}
