// The compress call end to end: synthetic sample -> compress_material -> .btfdb -> decode.
#include <doctest/doctest.h>

#include <filesystem>
#include <fstream>

#include "pipeline/encode/compress.h"
#include "pipeline/format/database.h"
#include <btfvq/error.h>
#include "pipeline/metrics/metrics.h"
#include "pipeline/decode/reconstruct.h"
#include "pipeline/io/synthetic.h"
#include "support/test_paths.h"

using namespace btfvq;
namespace fs = std::filesystem;

namespace {

MeasuredSample synth(const std::string& preset, int size, uint64_t seed = 1) {
  SynthOptions o;
  o.preset = preset;
  o.size = size;
  o.seed = seed;
  o.dynamic = Dynamic::LDR;
  return synthesize(o);
}

std::vector<uint8_t> file_bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

}  // namespace

TEST_CASE("round trip: the written file and the in-memory model decode identically, metrics are sane") {
  const MeasuredSample sample = synth("leather", 16);
  Database db;
  const CompressReport r = compress_material(db, sample, "leather", {});
  CHECK(r.json["phases"].size() == 3);
  // The shipped schedule refines between phases 2 and 3, so phase 3 assigns every texel.
  CHECK(r.json["phases"][2]["texels"] == 256);
  CHECK(r.json["refine"]["texels"].get<size_t>() >= r.json["phases"][0]["texels"].get<size_t>() + r.json["phases"][1]["texels"].get<size_t>());
  REQUIRE(!r.json["refine"]["iterations"].empty());
  for (const auto& it : r.json["refine"]["iterations"]) CHECK(it["mse_after"].get<double>() < it["mse_before"].get<double>());
  quantize_new_rows(db);
  const fs::path path = test::scratch_dir("compress-roundtrip") / "db.btfdb";
  write_database(db, path.string());
  const Database file = read_database(path.string());
  const MeasuredSample from_memory = reconstruct_sample(db, "leather", sample);
  const MeasuredSample from_file = reconstruct_sample(file, "leather", sample);
  CHECK(from_memory.ldr_data() == from_file.ldr_data());
  const EvaluationReport e = evaluate(sample, from_file);
  MESSAGE("16x16 leather: MSSIM " << e.mssim_y << ", PSNR " << e.psnr << ", CIEDE2000 " << e.ciede2000_mean);
  CHECK(e.mssim_y > 0.5);
  CHECK(e.psnr > 20.0);
  CHECK(e.ciede2000_mean < 8.0);
}

TEST_CASE("materials share code-books: one database of two is smaller than two databases of one") {
  const MeasuredSample a = synth("leather", 16, 1), b = synth("leather", 16, 2);
  const fs::path dir = test::scratch_dir("compress-shared");
  auto single = [&](const MeasuredSample& s, const std::string& name) {
    Database db;
    compress_material(db, s, name, {});
    write_database(db, (dir / (name + ".btfdb")).string());
    return fs::file_size(dir / (name + ".btfdb"));
  };
  const uintmax_t separate = single(a, "a") + single(b, "b");
  Database both;
  compress_material(both, a, "a", {});
  write_database(both, (dir / "both.btfdb").string());
  Database grown = read_database((dir / "both.btfdb").string());
  compress_material(grown, b, "b", {});
  write_database(grown, (dir / "both.btfdb").string());
  const uintmax_t together = fs::file_size(dir / "both.btfdb");
  MESSAGE("two single-material files " << separate << " bytes, one shared file " << together << " bytes");
  CHECK(together < separate);
}

TEST_CASE("adding a material keeps every existing section and decoded value") {
  const fs::path dir = test::scratch_dir("compress-append");
  const fs::path path = dir / "db.btfdb";
  Database db;
  compress_material(db, synth("tile", 12, 1), "tile", {});
  compress_material(db, synth("wood", 12, 1), "wood", {});
  quantize_new_rows(db);
  write_database(db, path.string());
  const auto v1 = file_bytes(path);
  const DatabaseHead head1 = parse_head(v1.data(), v1.size());
  const MeasuredSample tile_before = reconstruct_bonn(read_database(path.string()), "tile");

  Database grown = read_database(path.string());
  compress_material(grown, synth("wool", 12, 1), "wool", {});
  write_database(grown, path.string());
  const auto v2 = file_bytes(path);
  const DatabaseHead head2 = parse_head(v2.data(), v2.size());
  CHECK(head2.version == head1.version + 1);
  for (const SectionEntry& s : head1.sections) {
    bool found = false;
    for (const SectionEntry& t : head2.sections)
      if (t.kind == s.kind && t.version == s.version && t.codebook == s.codebook && t.material == s.material) {
        found = true;
        REQUIRE(t.length == s.length);
        CHECK(std::equal(v1.begin() + long(s.offset), v1.begin() + long(s.offset + s.length), v2.begin() + long(t.offset)));
      }
    CHECK(found);
  }
  const Database after = read_database(path.string());
  CHECK(after.materials.size() == 3);
  CHECK(reconstruct_bonn(after, "tile").ldr_data() == tile_before.ldr_data());
}

TEST_CASE("bad requests change nothing") {
  const MeasuredSample s = synth("tile", 8);
  Database db;
  compress_material(db, s, "tile", {});
  const Database before = db;
  CHECK_THROWS_AS(compress_material(db, s, "tile", {}), InputError);  // name clash
  CompressOptions bad;
  bad.config.merge(ParameterDictionary::parse(R"({"thresholds": {"ssim": {"p4": -1}}})", "test"));
  CHECK_THROWS_AS(compress_material(db, s, "other", bad), ConfigError);
  CompressOptions typo;
  typo.config.merge(ParameterDictionary::parse(R"({"schedule": {"phase1_fractoin": 0.1}})", "test"));
  CHECK_THROWS_AS(compress_material(db, s, "other", typo), ConfigError);
  CHECK(db == before);
}

TEST_CASE("a cancelled compression throws CancelledError") {
  const MeasuredSample s = synth("tile", 8);
  Database db;
  CompressOptions o;
  o.cancelled = [] { return true; };
  CHECK_THROWS_AS(compress_material(db, s, "tile", o), CancelledError);
}
