#include "pipeline/encode/tile_parts.h"

#include <cstring>
#include <filesystem>

#include <btfvq/error.h>
#include "pipeline/encode/checkpoint.h"
#include "pipeline/util/atomic_file.h"
#include "pipeline/util/bytes.h"
#include "pipeline/util/sha256.h"

namespace btfvq {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr char kSampleMagic[8] = {'B', 'T', 'F', 'V', 'Q', 'S', 'M', '1'};
constexpr size_t kDigest = 64;

void copy_into(const fs::path& from, const fs::path& to) {
  std::error_code ec;
  fs::copy_file(from, to, fs::copy_options::overwrite_existing, ec);
  if (ec) throw InputError("cannot copy '" + from.string() + "' to '" + to.string() + "': " + ec.message());
}

}  // namespace

size_t write_tile_snapshot(const PhaseThreeWork& work, const std::string& dir) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw InputError("cannot create '" + dir + "': " + ec.message());
  const fs::path from(work.folder), to(dir);
  copy_into(from / "state.ckpt", to / "state.ckpt");
  if (fs::exists(from / "tiles.log"))
    copy_into(from / "tiles.log", to / "tiles.log");
  else
    fs::remove(to / "tiles.log", ec);
  write_file_atomically((to / "config.json").string(), work.config.dump(1));
  write_file_atomically((to / "fingerprint").string(), work.fingerprint);
  // What the copy holds (the log may have grown since the caller looked).
  CheckpointFolder copy(dir, work.fingerprint);
  const auto saved = copy.load();
  if (!saved || !saved->phase3) throw Error("internal", "the tile snapshot " + dir + " holds no phase-3 state");
  return copy.p4_rows();
}

void write_raw_sample(const MeasuredSample& s, const std::string& path) {
  ByteWriter w;
  w.bytes.assign(kSampleMagic, sizeof kSampleMagic);
  w.put(int32_t(s.width()));
  w.put(int32_t(s.height()));
  w.put(uint8_t(s.dynamic()));
  w.put(uint64_t(s.view_count()));
  for (size_t v = 0; v < s.view_count(); ++v) {
    w.put(s.views()[v]);
    w.put(s.lights(v));
  }
  if (s.is_hdr())
    w.bytes.append(reinterpret_cast<const char*>(s.hdr_data().data()), s.hdr_data().size() * sizeof(float));
  else
    w.bytes.append(reinterpret_cast<const char*>(s.ldr_data().data()), s.ldr_data().size());
  write_file_atomically(path, w.bytes);
}

MeasuredSample read_raw_sample(const std::string& path) {
  const std::string in = read_file(path);
  if (in.size() < sizeof kSampleMagic || std::memcmp(in.data(), kSampleMagic, sizeof kSampleMagic) != 0)
    throw InputError("'" + path + "' is not a raw sample (btfvq tile reads what the server wrote)");
  ByteReader r(in.data() + sizeof kSampleMagic, in.size() - sizeof kSampleMagic, "raw sample");
  const int width = r.get<int32_t>(), height = r.get<int32_t>();
  const Dynamic dynamic = Dynamic(r.get<uint8_t>());
  const uint64_t views = r.get<uint64_t>();
  if (views > in.size()) throw CorruptError("raw sample: a view count past the end");
  std::vector<Direction> view_list;
  std::vector<std::vector<Direction>> lights(views);
  for (uint64_t v = 0; v < views; ++v) {
    view_list.push_back(r.get<Direction>());
    r.get(lights[v]);
  }
  MeasuredSample s(width, height, view_list, lights, dynamic);
  const size_t bytes = s.is_hdr() ? s.hdr_data().size() * sizeof(float) : s.ldr_data().size();
  if (r.left() != bytes)
    throw CorruptError("raw sample: " + std::to_string(r.left()) + " value bytes where the geometry needs " + std::to_string(bytes));
  std::memcpy(s.is_hdr() ? static_cast<void*>(s.hdr_data().data()) : static_cast<void*>(s.ldr_data().data()),
              r.take(bytes), bytes);
  return s;
}

TilePart check_tile_part(const std::string& out) {
  const std::string manifest_path = out + ".json";
  if (!fs::exists(manifest_path)) throw InputError("the tile part " + out + " is not finished (no manifest)");
  TilePart p;
  try {
    const json m = json::parse(read_file(manifest_path));
    p.first = m.at("first");
    p.end = m.at("end");
    p.p4_from = m.at("p4_from");
    p.p4_end = m.at("p4_end");
    p.bytes = m.at("bytes");
    p.sha256 = m.at("sha256");
    p.load_seconds = m.at("load_seconds");
    p.seconds = m.at("seconds");
    p.tile_seconds = m.at("tile_seconds");
  } catch (const json::exception& e) {
    throw CorruptError("the manifest of the tile part " + out + " is damaged: " + e.what());
  }
  const std::string bytes = read_file(out);
  if (bytes.size() != p.bytes)
    throw CorruptError("the tile part " + out + " has " + std::to_string(bytes.size()) + " bytes, its manifest says " +
                       std::to_string(p.bytes));
  if (sha256_hex(bytes) != p.sha256) throw CorruptError("the tile part " + out + " does not match its SHA-256");
  // One record per tile, numbered first+1 .. end (tiles done after it), each with its own digest.
  size_t at = 0, tile = p.first;
  while (at < bytes.size()) {
    uint64_t n;
    if (sizeof n > bytes.size() - at) throw CorruptError("the tile part " + out + ": a torn record");
    std::memcpy(&n, bytes.data() + at, sizeof n);
    at += sizeof n;
    if (n < 4 * sizeof(uint64_t) || n > bytes.size() - at || kDigest > bytes.size() - at - n)
      throw CorruptError("the tile part " + out + ": a torn record");
    const std::string body = bytes.substr(at, size_t(n));
    if (sha256_hex(body) != bytes.substr(at + size_t(n), kDigest))
      throw CorruptError("the tile part " + out + ": a record does not match its SHA-256");
    uint64_t done, from;
    std::memcpy(&done, body.data() + sizeof(uint64_t), sizeof done);
    std::memcpy(&from, body.data() + 2 * sizeof(uint64_t), sizeof from);
    if (done != tile + 1) throw CorruptError("the tile part " + out + ": tile records out of order");
    if (tile == p.first && from != p.p4_from) throw CorruptError("the tile part " + out + ": P4 rows differ from the manifest");
    ++tile;
    at += size_t(n) + kDigest;
  }
  if (tile != p.end)
    throw CorruptError("the tile part " + out + " holds " + std::to_string(tile - p.first) + " tiles, not " +
                       std::to_string(p.end - p.first));
  return p;
}

void merge_tile_part(const PhaseThreeWork& work, const std::string& out) {
  CheckpointFolder folder(work.folder, work.fingerprint);
  folder.append_records(read_file(out));
}

}  // namespace btfvq
