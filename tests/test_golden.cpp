// Golden files (tests/golden/README.md): databases written by earlier versions of btfvq open and
// decode to exactly the values they decoded to when they were written, and the database the demo
// writes is the one recorded (a change of the encoder's output shows here first, on purpose).
#include <doctest/doctest.h>

#include <cstring>
#include <filesystem>
#include <random>

#include <btfvq/renderer_api.h>
#include "pipeline/decode/decoder.h"
#include "pipeline/encode/compress.h"
#include "pipeline/format/database.h"
#include "pipeline/io/sample_io.h"
#include "pipeline/io/synthetic.h"
#include "pipeline/util/sha256.h"
#include "support/test_paths.h"

using namespace btfvq;
namespace fs = std::filesystem;

namespace {

fs::path golden(const std::string& name) { return test::source_dir() / "tests" / "golden" / name; }

// sha256 of the decoded RGB floats at 4096 fixed queries per material (texels and measured Bonn
// directions drawn from a fixed seed), on the C++ reference path.
std::string decoded_hash(const Database& db) {
  const Decoder decoder(db);
  std::mt19937 rng(2010);
  const auto& dirs = bonn81();
  std::vector<DecodeQuery> queries;
  for (uint32_t m = 0; m < db.materials.size(); ++m)
    for (int i = 0; i < 4096; ++i)
      queries.push_back({m, int32_t(rng() % uint32_t(db.materials[m].width)), int32_t(rng() % uint32_t(db.materials[m].height)),
                         dirs[rng() % dirs.size()], dirs[rng() % dirs.size()]});
  const std::vector<Rgb> rgb = decoder.decode_reference(queries);
  std::string bytes(rgb.size() * sizeof(Rgb), '\0');
  std::memcpy(bytes.data(), rgb.data(), bytes.size());
  return sha256_hex(bytes);
}

}  // namespace

TEST_CASE("a database written before the code-book economy change opens and decodes as it did") {
  // Written at commit c864d0e: synth leather 16 seed 3 (LDR) then wood 16 seed 4 --hdr appended, by
  // `btfvq compress` at the shipped defaults: two versions, range-coded sections, one HDR material.
  const fs::path file = golden("pre_economy_two_versions.btfdb");
  CHECK(sha256_file(file.string()) == "06cec5237d64b799ae5e61ca1daba7aac112516b593394b0cc2b0c89d57b9555");
  const Database db = read_database(file.string());
  REQUIRE(db.versions.size() == 2);
  REQUIRE(db.materials.size() == 2);
  CHECK(db.materials[1].dynamic == Dynamic::HDR);
  CHECK(decoded_hash(db) == "e6a863614f7de8b107b132a0f036b6e7b4ec57acf4559ca3942a69e584c0bb95");
  // The renderer API reads it too, and agrees with the decoder underneath.
  const BtfDatabase api = BtfDatabase::open(file.string());
  const Rgb a = api.material("leather").evaluate(0.5 / 16, 0.5 / 16, Direction{45, 120}, Direction{30, 60});
  const Rgb b = Decoder(db).evaluate(0, 0, 0, Direction{45, 120}, Direction{30, 60});
  CHECK(a.r == b.r);
  CHECK(a.g == b.g);
  CHECK(a.b == b.b);
}

TEST_CASE("the demo's database: synth leather 64 seed 1 as a JPEG zip, compressed at the shipped defaults") {
  const fs::path dir = test::scratch_dir("golden-demo");
  SynthOptions o;
  o.preset = "leather";
  o.size = 64;
  o.seed = 1;
  write_sample(synthesize(o), (dir / "leather.zip").string());
  const std::string zip = (dir / "leather.zip").string();
  const DatabaseSummary s = compress_database(
      "", {{"leather", "load", [&](const ProgressFn& p) { return load_sample(zip, p); }}}, (dir / "demo.btfdb").string(), {});
  CHECK(s.bytes == fs::file_size(dir / "demo.btfdb"));
  // What `make demo` writes (it compresses the same zip through the server). Recorded when the
  // refinement and phase 3 came to choose entries by MSE (schedule.assign_metric, session 36);
  // before, bd8a43a6...1e69, when the P3
  // and M proxy signatures took the luminance in three bands (session 30); before, 815d1e70...80f478,
  // when P4 scales kept only the codes a 0.25 % error needs (session 29); before, c39623c2...4be6fb7, when P4's new
  // rows were numbered in the order the P6 first reaches them (session 29); before, a95e7b66...254e7f,
  // when the refinement's merges got a budget per material, P2 merges a larger radius and p4 0.075 (session
  // 9); before, 0983cfe2...4a8d3, when the
  // refinement (Lloyd iterations with merges) came between phases 2 and 3 and the thresholds below
  // P3 tightened (session 8); before, 2cda20c6...2609d1, when phase
  // 1 shrank to 0.4 % of the texels and every threshold moved x 0.9 (session 7); before,
  // 87e55727...38ce4, when the resampling stopped inventing the horizon (unseen nodes repeat their nearest seen node) and the
  // composition threshold moved to 0.32 (session 7); before, eff577ef...2d9a, recorded when the
  // phase-3 composition became a default (session 6; 068f3357...3c6398 before the adoption check
  // looked only at adopted entries sharing half their P3 entries); before, 5b951909...c65969 (code-book economy)
  // and, at ff20a73, 0c607eed...f2f9d8.
  CHECK(sha256_file((dir / "demo.btfdb").string()) == "9bf5c3807d36d5a326620d6ed3f869853b6e2c7083eeddefbef29f647c21873c");
}
