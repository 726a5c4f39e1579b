// Checkpoints (pipeline/encode/checkpoint.h): a compression stopped in phase 3 continues from its
// last completed tile and writes the very bytes of an uninterrupted run; torn, damaged or foreign
// checkpoints are never trusted.
#include <doctest/doctest.h>

#include <atomic>
#include <filesystem>
#include <fstream>

#include <btfvq/error.h>
#include "pipeline/encode/checkpoint.h"
#include "pipeline/encode/compress.h"
#include "pipeline/format/database.h"
#include "pipeline/io/synthetic.h"
#include "support/test_paths.h"

using namespace btfvq;
namespace fs = std::filesystem;

namespace {

std::string file_bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

MaterialInput synthetic(const std::string& preset, int size, std::atomic<int>* loads = nullptr) {
  return {preset, "synthesize",
          [=](const ProgressFn&) {
            if (loads) ++*loads;
            SynthOptions o;
            o.preset = preset;
            o.size = size;
            o.seed = 3;
            return synthesize(o);
          },
          preset + std::to_string(size)};
}

// Phase-3 tiles of the shipped schedule (256 texels each) on a 32 x 32 sample: 4, all texels being
// assigned in phase 3 after the refinement.
constexpr size_t kTile = 256;

struct Outcome {
  bool cancelled = false;
  int64_t resumed_tile = -1;  // the smallest reported
};

// compress_database into `out` with checkpoints in `work`; stops (as a kill would, between tiles)
// once `stop_after` phase-3 tiles of material `stop_material` are done (0: never).
Outcome compress(const std::vector<MaterialInput>& inputs, const fs::path& out, const fs::path& work,
                 size_t stop_after = 0, const std::string& stop_material = "",
                 const nlohmann::json& overrides = nlohmann::json::object()) {
  Outcome o;
  std::atomic<bool> stop{false};
  CompressOptions options;
  options.config = pipeline_config(overrides, "test");
  if (!work.empty()) options.checkpoint_folder = work.string();
  options.progress = [&](const CompressProgress& p) {
    if (p.resumed_tile >= 0 && (o.resumed_tile < 0 || p.resumed_tile < o.resumed_tile)) o.resumed_tile = p.resumed_tile;
    if (stop_after && p.stage == "phase3" && p.material == stop_material && p.texels_done >= stop_after * kTile) stop = true;
  };
  options.cancelled = [&] { return stop.load(); };
  try {
    compress_database("", inputs, out.string(), options);
  } catch (const CancelledError&) {
    o.cancelled = true;
  }
  return o;
}

}  // namespace

TEST_CASE("stopped after two phase-3 tiles, a compression continues from the third and writes the same bytes") {
  const fs::path dir = test::scratch_dir("checkpoint-resume");
  const std::vector<MaterialInput> inputs = {synthetic("leather", 32)};
  REQUIRE_FALSE(compress(inputs, dir / "reference.btfdb", {}).cancelled);
  const std::string reference = file_bytes(dir / "reference.btfdb");
  REQUIRE(!reference.empty());

  const fs::path work = dir / "work";
  REQUIRE(compress(inputs, dir / "db.btfdb", work, 2, "leather").cancelled);
  CHECK_FALSE(fs::exists(dir / "db.btfdb"));  // nothing half-done is written
  CHECK(fs::is_regular_file(work / "state.ckpt"));
  CHECK(fs::file_size(work / "tiles.log") > 0);

  const Outcome resumed = compress(inputs, dir / "db.btfdb", work);
  CHECK_FALSE(resumed.cancelled);
  CHECK(resumed.resumed_tile == 2);
  CHECK(file_bytes(dir / "db.btfdb") == reference);
  remove_checkpoints(work.string());
  CHECK_FALSE(fs::exists(work));
}

TEST_CASE("with schedule.compose_p3 (in half the texels) phase 3 also appends P3 rows: the resumed compression writes the same bytes") {
  const fs::path dir = test::scratch_dir("checkpoint-compose-p3");
  const std::vector<MaterialInput> inputs = {synthetic("leather", 32)};
  // A share below 1 (the quality rule's ramp over Q 90..92) picks texels by their place in the
  // whole Halton order, so the resumed tiles pick the same ones.
  const nlohmann::json on = {{"schedule", {{"compose_p3", true}, {"compose_p3_share", 0.5}}}};
  REQUIRE_FALSE(compress(inputs, dir / "reference.btfdb", {}, 0, "", on).cancelled);
  REQUIRE_FALSE(compress(inputs, dir / "without.btfdb", {}).cancelled);
  const Database with = read_database((dir / "reference.btfdb").string());
  const Database without = read_database((dir / "without.btfdb").string());
  // The growing phases are the same, so the extra P3 rows are phase 3's.
  REQUIRE(with.codebooks.p3_index.rows() > without.codebooks.p3_index.rows());

  const fs::path work = dir / "work";
  REQUIRE(compress(inputs, dir / "db.btfdb", work, 2, "leather", on).cancelled);
  const Outcome resumed = compress(inputs, dir / "db.btfdb", work, 0, "", on);
  CHECK(resumed.resumed_tile == 2);
  CHECK(file_bytes(dir / "db.btfdb") == file_bytes(dir / "reference.btfdb"));
}

TEST_CASE("a tile record torn by the kill is dropped: that tile is encoded again, the bytes are the same") {
  const fs::path dir = test::scratch_dir("checkpoint-torn");
  const std::vector<MaterialInput> inputs = {synthetic("leather", 32)};
  REQUIRE_FALSE(compress(inputs, dir / "reference.btfdb", {}).cancelled);
  const fs::path work = dir / "work";
  REQUIRE(compress(inputs, dir / "db.btfdb", work, 2, "leather").cancelled);
  fs::resize_file(work / "tiles.log", fs::file_size(work / "tiles.log") - 10);
  const Outcome resumed = compress(inputs, dir / "db.btfdb", work);
  CHECK(resumed.resumed_tile == 1);
  CHECK(file_bytes(dir / "db.btfdb") == file_bytes(dir / "reference.btfdb"));
}

TEST_CASE("a damaged state, or the checkpoint of other work, is not resumed from") {
  const fs::path dir = test::scratch_dir("checkpoint-foreign");
  const std::vector<MaterialInput> inputs = {synthetic("leather", 32)};
  REQUIRE_FALSE(compress(inputs, dir / "reference.btfdb", {}).cancelled);
  const std::string reference = file_bytes(dir / "reference.btfdb");
  const fs::path work = dir / "work";

  SUBCASE("one byte of the state changed") {
    REQUIRE(compress(inputs, dir / "db.btfdb", work, 2, "leather").cancelled);
    std::fstream f(work / "state.ckpt", std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(200);
    f.put('\x5a');
    f.close();
    const Outcome again = compress(inputs, dir / "db.btfdb", work);
    CHECK(again.resumed_tile == -1);
    CHECK(file_bytes(dir / "db.btfdb") == reference);
  }
  SUBCASE("another input under the same name") {
    MaterialInput other = synthetic("leather", 32);
    other.identity = "another leather";
    REQUIRE(compress({other}, dir / "db.btfdb", work, 2, "leather").cancelled);
    const Outcome again = compress(inputs, dir / "db.btfdb", work);
    CHECK(again.resumed_tile == -1);
    CHECK(file_bytes(dir / "db.btfdb") == reference);
  }
}

TEST_CASE("two inputs, stopped in the second's phase 3: the first is not compressed again, the bytes are the same") {
  const fs::path dir = test::scratch_dir("checkpoint-two");
  std::atomic<int> loads{0};
  const std::vector<MaterialInput> inputs = {synthetic("tile", 16, &loads), synthetic("leather", 32)};
  REQUIRE_FALSE(compress(inputs, dir / "reference.btfdb", {}).cancelled);
  const fs::path work = dir / "work";
  REQUIRE(compress(inputs, dir / "db.btfdb", work, 3, "leather").cancelled);
  loads = 0;
  const Outcome resumed = compress(inputs, dir / "db.btfdb", work);
  CHECK(resumed.resumed_tile == 3);
  CHECK(loads == 0);
  CHECK(file_bytes(dir / "db.btfdb") == file_bytes(dir / "reference.btfdb"));
}
