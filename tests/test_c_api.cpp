// The C header gives exactly what the C++ API gives: a database written as a .btfdb, values computed
// here through BtfDatabase, then tests/c_api_test.c (compiled as C) run with them on its command line.
#include <doctest/doctest.h>

#include <cstdio>
#include <string>

#include "pipeline/io/btfbase.h"
#include "pipeline/format/database.h"
#include <btfvq/renderer_api.h>
#include "support/test_paths.h"

using namespace btfvq;

TEST_CASE("the C program decodes and samples the same values as the C++ API") {
  const auto path = test::scratch_dir("c_api") / "alu.btfdb";
  write_database(import_btfbase((test::testdata_dir() / "btfbase" / "alu").string()), path.string(),
                 PackSettings::lossless());
  const BtfDatabase db = BtfDatabase::open(path.string());
  const BtfMaterial mat = db.material("alu");
  struct Query {
    double u, v, ti, pi, tv, pv, xi1, xi2;
  };
  for (const Query& q : {Query{0.33, 0.71, 45, 120, 30, 60, 0.25, 0.6}, Query{0.9, 0.05, 70, 10, 5, 300, 0.99, 0.01},
                         Query{0.5, 0.5, 12.5, 200, 80, 45, 0.5, 0.5}}) {
    const Rgb c = mat.evaluate(q.u, q.v, to_vector({q.ti, q.pi}), to_vector({q.tv, q.pv}));
    const BtfSample s = mat.sample(q.u, q.v, to_vector({q.tv, q.pv}), q.xi1, q.xi2);
    CHECK(c.g > 0);
    char args[1024];
    std::snprintf(args, sizeof args, "%s alu %.17g %.17g %.17g %.17g %.17g %.17g %.9g %.9g %.9g %.17g %.17g %.17g %.17g %.17g %.17g",
                  path.c_str(), q.u, q.v, q.ti, q.pi, q.tv, q.pv, double(c.r), double(c.g), double(c.b), q.xi1, q.xi2,
                  s.direction.x, s.direction.y, s.direction.z, s.pdf);
    std::string out;
    CHECK_MESSAGE(test::run_command((test::bin_dir() / "c_api_test").string() + " " + args, &out) == 0, out);
  }
}
