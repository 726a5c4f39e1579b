// Phase-3 tile parts (pipeline/encode/tile_parts.h, `btfvq tile`): parts computed from snapshots
// and merged in tile order give the local bytes; a part computed before an earlier tile composed
// says so (p4_from); a damaged part never passes the check.
#include <doctest/doctest.h>

#include <filesystem>
#include <fstream>

#include <btfvq/error.h>
#include "pipeline/encode/compress.h"
#include "pipeline/encode/tile_parts.h"
#include "pipeline/io/synthetic.h"
#include "support/test_paths.h"

using namespace btfvq;
using btfvq::test::scratch_dir;
namespace fs = std::filesystem;

namespace {

std::string file_bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void put_bytes(const fs::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out << bytes;
}

MaterialInput synthetic(const std::string& preset, int size, uint64_t seed) {
  return {preset, "synthesize",
          [=](const ProgressFn&) {
            SynthOptions o;
            o.preset = preset;
            o.size = size;
            o.seed = seed;
            return synthesize(o);
          },
          preset + std::to_string(size) + "/" + std::to_string(seed)};
}

}  // namespace

TEST_CASE("tile parts from snapshots, merged in tile order, give the local database; stale and damaged parts are told") {
  const fs::path dir = scratch_dir("tile-parts");
  const std::vector<MaterialInput> inputs = {synthetic("leather", 32, 3), synthetic("wood", 32, 4)};
  CompressOptions local;
  compress_database("", inputs, (dir / "local.btfdb").string(), local);

  size_t stale_seen = 0, damaged_seen = 0, parts = 0;
  CompressOptions remote;
  remote.checkpoint_folder = (dir / "work").string();
  remote.remote_phase3 = [&](const PhaseThreeWork& w) {
    const fs::path here = dir / ("input-" + std::to_string(w.input));
    fs::create_directories(here);
    const std::string sample = (here / "sample.raw").string();
    write_raw_sample(*w.sample, sample);
    CHECK(read_raw_sample(sample).ldr_data() == w.sample->ldr_data());
    size_t merged = w.tiles_done, p4 = w.p4_rows;
    // Two tiles per part; every part also has a speculative twin for the part after it, from the
    // same snapshot: good only when the first part composed nothing.
    for (int wave = 0; merged < w.tiles; ++wave) {
      const fs::path snap = here / ("wave-" + std::to_string(wave));
      REQUIRE(write_tile_snapshot(w, snap.string()) == p4);
      const size_t end = std::min(w.tiles, merged + 2);
      const std::string part = (snap / "part-0").string();
      const TilePart p = compute_tile_part(snap.string(), sample, merged, end, part);
      ++parts;
      CHECK(p.first == merged);
      CHECK(p.end == end);
      CHECK(p.p4_from == p4);
      CHECK(p.tile_seconds.size() == end - merged);
      CHECK(check_tile_part(part).sha256 == p.sha256);
      if (end < w.tiles) {  // the speculative twin
        const std::string twin = (snap / "part-1").string();
        const TilePart q = compute_tile_part(snap.string(), sample, end, std::min(w.tiles, end + 2), twin);
        CHECK(q.p4_from == p4);
        if (p.p4_end != p.p4_from) ++stale_seen;  // the merge would compute it again
        // Damaged: a flipped byte, a torn end, a manifest that promises another tile count.
        const std::string good = file_bytes(twin);
        std::string bad = good;
        bad[bad.size() / 2] ^= 1;
        put_bytes(twin, bad);
        CHECK_THROWS_AS(check_tile_part(twin), CorruptError);
        put_bytes(twin, good.substr(0, good.size() - 10));
        CHECK_THROWS_AS(check_tile_part(twin), CorruptError);
        put_bytes(twin, good);
        CHECK_NOTHROW(check_tile_part(twin));
        ++damaged_seen;
      }
      merge_tile_part(w, part);
      merged = p.end;
      p4 = p.p4_end;
      w.progress(merged);
    }
  };
  compress_database("", inputs, (dir / "remote.btfdb").string(), remote);
  CHECK(file_bytes(dir / "remote.btfdb") == file_bytes(dir / "local.btfdb"));
  CHECK(parts >= 4);  // two materials of 4 tiles, 2 tiles per part
  CHECK(damaged_seen > 0);
  MESSAGE("parts whose twin would be stale: " << stale_seen);

  SUBCASE("a part of tiles the sample does not have, or before the snapshot, is refused") {
    // (the work folder is gone after a finished input; the checks come before any snapshot is read)
    CHECK_THROWS_AS(compute_tile_part((dir / "nowhere").string(), (dir / "input-0" / "sample.raw").string(), 0, 1,
                                      (dir / "x").string()),
                    InputError);
    CHECK_THROWS_AS(check_tile_part((dir / "x").string()), InputError);
  }
}

TEST_CASE("with schedule.compose_p3 the parts carry the P3 rows their tiles composed: merged, the bytes are the local ones") {
  const fs::path dir = scratch_dir("tile-parts-p3");
  const std::vector<MaterialInput> inputs = {synthetic("leather", 32, 3)};
  CompressOptions local;
  local.config = pipeline_config({{"schedule", {{"compose_p3", true}}}}, "test");
  compress_database("", inputs, (dir / "local.btfdb").string(), local);

  CompressOptions remote = local;
  remote.checkpoint_folder = (dir / "work").string();
  size_t parts = 0;
  remote.remote_phase3 = [&](const PhaseThreeWork& w) {
    const std::string sample = (dir / "sample.raw").string();
    write_raw_sample(*w.sample, sample);
    for (size_t merged = w.tiles_done; merged < w.tiles; ++parts) {
      const fs::path snap = dir / ("wave-" + std::to_string(parts));
      write_tile_snapshot(w, snap.string());
      const std::string part = (snap / "part").string();
      const TilePart p = compute_tile_part(snap.string(), sample, merged, std::min(w.tiles, merged + 2), part);
      CHECK(check_tile_part(part).sha256 == p.sha256);
      merge_tile_part(w, part);
      merged = p.end;
      w.progress(merged);
    }
  };
  compress_database("", inputs, (dir / "remote.btfdb").string(), remote);
  CHECK(parts >= 2);
  CHECK(file_bytes(dir / "remote.btfdb") == file_bytes(dir / "local.btfdb"));
}
