#include "pipeline/encode/checkpoint.h"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>

#include <btfvq/error.h>
#include "pipeline/util/atomic_file.h"
#include "pipeline/util/bytes.h"
#include "pipeline/util/sha256.h"

namespace btfvq {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr char kStateMagic[8] = {'B', 'T', 'F', 'V', 'Q', 'C', 'K', '1'};
constexpr size_t kDigest = 64;  // hex SHA-256 after every state body and log record

using Writer = ByteWriter;
using Reader = ByteReader;

template <class T>
void put_table(Writer& w, const Table<T>& t) {
  w.put(uint64_t(t.cols()));
  w.put(t.data());
}

template <class T>
void get_table(Reader& r, Table<T>& t) {
  if (r.get<uint64_t>() != t.cols()) throw CorruptError("checkpoint: a code-book of another grid");
  r.get(t.data());
  if (t.cols() && t.data().size() % t.cols()) throw CorruptError("checkpoint: a partial code-book row");
}

// Every table of the code-books, in one order for writing and reading.
template <class K, class F>
void each_table(K& k, F f) {
  f(k.p1), f(k.c), f(k.i1), f(k.i2), f(k.p2_index), f(k.p2_scale), f(k.m), f(k.p3_index), f(k.p3_scale),
      f(k.p4_index), f(k.p4_scale);
}

json stats_json(const EncoderStats& s) {
  return {{"texels", s.texels}, {"comparisons", s.comparisons}, {"pruned", s.pruned}, {"fallbacks", s.fallbacks},
          {"laesa_skipped", s.laesa_skipped}, {"miss", s.inserted_miss}, {"retry", s.inserted_retry},
          {"exact", s.inserted_exact}, {"reused", s.reused},
          {"ahead", {s.ahead, s.ahead_extended, s.ahead_redone}}, {"rows_ahead", {s.rows_ahead, s.rows_redone}}};
}

EncoderStats stats_of(const json& j) {
  EncoderStats s;
  s.texels = j.at("texels");
  s.comparisons = j.at("comparisons");
  s.pruned = j.at("pruned");
  s.fallbacks = j.at("fallbacks");
  s.laesa_skipped = j.at("laesa_skipped");
  s.inserted_miss = j.at("miss");
  s.inserted_retry = j.at("retry");
  s.inserted_exact = j.at("exact");
  s.reused = j.at("reused");
  if (j.contains("ahead")) {  // checkpoints written before the parts were searched ahead have none
    s.ahead = j["ahead"].at(0);
    s.ahead_extended = j["ahead"].at(1);
    s.ahead_redone = j["ahead"].at(2);
  }
  if (j.contains("rows_ahead")) {  // nor those written before the rows were
    s.rows_ahead = j["rows_ahead"].at(0);
    s.rows_redone = j["rows_ahead"].at(1);
  }
  return s;
}

json report_json(const ScheduleReport& r) {
  json steps = json::array();
  for (const RefineStep& s : r.refine) steps.push_back({s.mse_before, s.mse_after});
  json j = {{"encoder", stats_json(r.encoder)}, {"search", int(r.search)}, {"composed", r.composed},
            {"propose_seconds", r.propose_seconds}, {"adopt_seconds", r.adopt_seconds},
            {"refine_texels", r.refine_texels}, {"refine", steps}, {"refine_seconds", r.refine_seconds},
            {"phases", json::array()}};
  for (int p = 0; p < 3; ++p) j["phases"].push_back({r.texels[p], r.sizes[p], r.seconds[p], r.cpu_seconds[p]});
  return j;
}

ScheduleReport report_of(const json& j) {
  ScheduleReport r;
  r.encoder = stats_of(j.at("encoder"));
  r.search = SearchPath(j.at("search").get<int>());
  r.composed = j.at("composed");
  r.propose_seconds = j.at("propose_seconds");
  r.adopt_seconds = j.at("adopt_seconds");
  r.refine_texels = j.at("refine_texels");
  r.refine_seconds = j.at("refine_seconds");
  for (const auto& s : j.at("refine")) r.refine.push_back({s.at(0), s.at(1)});
  for (int p = 0; p < 3; ++p) {
    const json& ph = j.at("phases").at(size_t(p));
    r.texels[p] = ph.at(0);
    r.sizes[p] = ph.at(1).get<CodebookSizes>();
    r.seconds[p] = ph.at(2);
    r.cpu_seconds[p] = ph.at(3);
  }
  return r;
}

// The rows of a composite code-book (indices and scales) from row `from` on.
void put_rows(Writer& w, const Table<uint32_t>& index, const Table<float>& scale, size_t from) {
  const ptrdiff_t at = ptrdiff_t(from * index.cols());
  w.put(std::vector<uint32_t>(index.data().begin() + at, index.data().end()));
  w.put(std::vector<float>(scale.data().begin() + at, scale.data().end()));
}

// Rows read by put_rows' counterpart, appended when they are whole rows.
bool append_rows(Reader& r, Table<uint32_t>& index, Table<float>& scale) {
  std::vector<uint32_t> i;
  std::vector<float> s;
  r.get(i);
  r.get(s);
  if (i.size() != s.size() || i.size() % index.cols()) return false;
  index.data().insert(index.data().end(), i.begin(), i.end());
  scale.data().insert(scale.data().end(), s.begin(), s.end());
  return true;
}

uint64_t generation_of(const std::string& digest) { return std::stoull(digest.substr(0, 16), nullptr, 16); }

std::string read_all(const std::string& path) { return fs::exists(path) ? read_file(path) : std::string(); }

// Appends and makes durable before returning: a tile is done only once its record is on disk.
// Failures are atomic_file's errors (a full disk is a NoSpaceError naming ENOSPC).
void append_durably(const std::string& path, const std::string& bytes) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) throw_write_error(path, errno);
  try {
    write_all(fd, bytes.data(), bytes.size(), path);
    if (::fdatasync(fd) != 0) throw_write_error(path, errno);
  } catch (...) {
    ::close(fd);
    throw;
  }
  if (::close(fd) != 0) throw_write_error(path, errno);
}

}  // namespace

CheckpointFolder::CheckpointFolder(std::string folder, std::string fingerprint)
    : folder_(std::move(folder)), fingerprint_(std::move(fingerprint)) {
  std::error_code ec;
  fs::create_directories(folder_, ec);
  if (ec) throw InputError("cannot create the work folder '" + folder_ + "': " + ec.message());
}

std::string CheckpointFolder::state_path() const { return (fs::path(folder_) / "state.ckpt").string(); }
std::string CheckpointFolder::log_path() const { return (fs::path(folder_) / "tiles.log").string(); }

void CheckpointFolder::save_state(size_t input, const Database& db, size_t first_new, const PhaseThreeState* phase3) {
  Writer w;
  w.bytes.append(kStateMagic, sizeof kStateMagic);
  w.put(fingerprint_);
  w.put(uint64_t(input));
  const AngularGrid& g = db.codebooks.grid;
  for (int v : {g.n_beta, g.n_alpha, g.n_theta_v, g.n_phi_v}) w.put(int32_t(v));
  each_table(db.codebooks, [&](const auto& t) { put_table(w, t); });
  w.put(uint64_t(db.materials.size() - first_new));
  for (size_t i = first_new; i < db.materials.size(); ++i) {
    const Material& m = db.materials[i];
    w.put(m.name);
    w.put(int32_t(m.width));
    w.put(int32_t(m.height));
    w.put(uint8_t(m.dynamic));
    w.put(m.raw_bytes);
    w.put(m.p6_index);
    w.put(m.p6_scale);
  }
  w.put(uint8_t(phase3 ? 1 : 0));
  if (phase3) {
    w.put(uint64_t(phase3->tiles_done));
    w.put(phase3->result.p6_index);
    w.put(phase3->result.p6_scale);
    w.put(phase3->result.dissimilarity);
    w.put(report_json(phase3->result.report).dump());
  }
  const std::string digest = sha256_hex(w.bytes);
  write_file_atomically(state_path(), w.bytes + digest);
  // The old records belong to the old state (their generation says so); removing them keeps the log short.
  std::error_code ec;
  fs::remove(log_path(), ec);
  generation_ = generation_of(digest);
  logged_ = CodebookSizes::of(db.codebooks);
}

void CheckpointFolder::append_tile(size_t tiles_done, const Codebooks& books, const ScheduleResult& so_far,
                                   std::span<const uint32_t> tile) {
  const CodebookSizes now = CodebookSizes::of(books);
  for (CodebookId id : kAllCodebooks)
    if (id != CodebookId::P4 && id != CodebookId::P3 && now[id] != logged_[id])
      throw Error("internal", std::string("checkpoint: phase 3 changed code-book ") + codebook_name(id));
  Writer w;
  w.put(generation_);
  w.put(uint64_t(tiles_done));
  const size_t p4_from = logged_[CodebookId::P4], p3_from = logged_[CodebookId::P3];
  w.put(uint64_t(p4_from));
  w.put(uint64_t(p3_from));
  put_rows(w, books.p4_index, books.p4_scale, p4_from);
  put_rows(w, books.p3_index, books.p3_scale, p3_from);
  std::vector<uint32_t> ids(tile.begin(), tile.end());
  std::vector<int32_t> index;
  std::vector<float> scale, dissimilarity;
  for (uint32_t id : ids) {
    index.push_back(so_far.p6_index[id]);
    scale.push_back(so_far.p6_scale[id]);
    dissimilarity.push_back(so_far.dissimilarity[id]);
  }
  w.put(ids);
  w.put(index);
  w.put(scale);
  w.put(dissimilarity);
  w.put(report_json(so_far.report).dump());
  Writer record;
  record.put(uint64_t(w.bytes.size()));
  append_durably(log_override_.empty() ? log_path() : log_override_, record.bytes + w.bytes + sha256_hex(w.bytes));
  logged_ = now;
}

void CheckpointFolder::append_records(const std::string& bytes) { append_durably(log_path(), bytes); }

std::optional<SavedWork> CheckpointFolder::load() {
  const std::string state = read_all(state_path());
  if (state.empty()) return std::nullopt;
  SavedWork saved;
  try {
    if (state.size() < sizeof kStateMagic + kDigest || std::memcmp(state.data(), kStateMagic, sizeof kStateMagic) != 0)
      throw CorruptError("not a checkpoint");
    const std::string body = state.substr(0, state.size() - kDigest);
    const std::string digest = state.substr(body.size());
    if (sha256_hex(body) != digest) throw CorruptError("its checksum does not match");
    Reader r(body.data() + sizeof kStateMagic, body.size() - sizeof kStateMagic, "checkpoint");
    if (r.str() != fingerprint_) {
      spdlog::info("the work folder {} holds the checkpoint of other work: starting from the beginning", folder_);
      return std::nullopt;
    }
    saved.input = size_t(r.get<uint64_t>());
    AngularGrid g;
    g.n_beta = r.get<int32_t>();
    g.n_alpha = r.get<int32_t>();
    g.n_theta_v = r.get<int32_t>();
    g.n_phi_v = r.get<int32_t>();
    g.validate();
    saved.codebooks = Codebooks(g);
    each_table(saved.codebooks, [&](auto& t) { get_table(r, t); });
    for (uint64_t n = r.get<uint64_t>(); n > 0; --n) {
      Material m;
      m.name = r.str();
      m.width = r.get<int32_t>();
      m.height = r.get<int32_t>();
      m.dynamic = Dynamic(r.get<uint8_t>());
      m.raw_bytes = r.get<uint64_t>();
      r.get(m.p6_index);
      r.get(m.p6_scale);
      saved.finished.push_back(std::move(m));
    }
    if (r.get<uint8_t>()) {
      PhaseThreeState p;
      p.tiles_done = size_t(r.get<uint64_t>());
      r.get(p.result.p6_index);
      r.get(p.result.p6_scale);
      r.get(p.result.dissimilarity);
      p.result.report = report_of(json::parse(r.str()));
      saved.phase3 = std::move(p);
    }
    if (!r.done()) throw CorruptError("bytes after the end");
    generation_ = generation_of(digest);
  } catch (const std::exception& e) {
    spdlog::warn("the checkpoint in {} is damaged ({}): starting from the beginning", folder_, e.what());
    return std::nullopt;
  }

  // Replay the tile records that continue this state, up to the first that does not (torn by the
  // kill, or of an older state); later appends go after the last good one.
  const std::string log = read_all(log_path());
  size_t good = 0;
  if (saved.phase3) {
    PhaseThreeState& p = *saved.phase3;
    Codebooks& k = saved.codebooks;
    while (good + sizeof(uint64_t) <= log.size()) {
      uint64_t n;
      std::memcpy(&n, log.data() + good, sizeof n);
      const size_t at = good + sizeof n;
      if (n > log.size() - at || kDigest > log.size() - at - n) break;
      const std::string body = log.substr(at, size_t(n));
      if (sha256_hex(body) != log.substr(at + size_t(n), kDigest)) break;
      try {
        Reader r(body.data(), body.size(), "checkpoint");
        if (r.get<uint64_t>() != generation_ || r.get<uint64_t>() != p.tiles_done + 1) break;
        if (r.get<uint64_t>() != k.p4_index.rows() || r.get<uint64_t>() != k.p3_index.rows()) break;
        Codebooks rows(k.grid);  // the record's new rows, kept apart until the record is whole
        if (!append_rows(r, rows.p4_index, rows.p4_scale) || !append_rows(r, rows.p3_index, rows.p3_scale)) break;
        std::vector<uint32_t> ids;
        std::vector<float> scale, dissimilarity;
        std::vector<int32_t> index;
        r.get(ids);
        r.get(index);
        r.get(scale);
        r.get(dissimilarity);
        const ScheduleReport report = report_of(json::parse(r.str()));
        if (index.size() != ids.size() || scale.size() != ids.size() || dissimilarity.size() != ids.size()) break;
        bool inside = true;
        for (uint32_t id : ids) inside = inside && id < p.result.p6_index.size();
        if (!inside) break;
        auto extend = [](auto& to, const auto& from) { to.data().insert(to.data().end(), from.data().begin(), from.data().end()); };
        extend(k.p4_index, rows.p4_index);
        extend(k.p4_scale, rows.p4_scale);
        extend(k.p3_index, rows.p3_index);
        extend(k.p3_scale, rows.p3_scale);
        for (size_t i = 0; i < ids.size(); ++i) {
          p.result.p6_index[ids[i]] = index[i];
          p.result.p6_scale[ids[i]] = scale[i];
          p.result.dissimilarity[ids[i]] = dissimilarity[i];
        }
        p.result.report = report;
        ++p.tiles_done;
      } catch (const std::exception&) {
        break;
      }
      good = at + size_t(n) + kDigest;
    }
  }
  std::error_code ec;
  if (good == 0)
    fs::remove(log_path(), ec);
  else if (good < log.size())
    fs::resize_file(log_path(), good, ec);
  logged_ = CodebookSizes::of(saved.codebooks);
  return saved;
}

void remove_checkpoints(const std::string& folder) {
  if (folder.empty()) return;
  std::error_code ec;
  fs::remove(fs::path(folder) / "state.ckpt", ec);
  fs::remove(fs::path(folder) / "tiles.log", ec);
  fs::remove(folder, ec);  // only if empty: a folder the user also keeps other files in stays
}

}  // namespace btfvq
