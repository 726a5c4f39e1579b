#include "server/catalogue.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <fstream>
#include <set>

#include "pipeline/format/database.h"
#include "pipeline/util/sha256.h"
#include <btfvq/error.h>

namespace btfvq::server {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

json version_json(const VersionRecord& v) {
  uint64_t raw = 0;
  for (const auto& m : v.materials) raw += m.value("raw_bytes", uint64_t(0));
  return {{"version", v.version},
          {"size", v.size},
          {"sha256", v.sha256},
          {"created", v.created},
          {"job", v.job},
          {"materials", v.materials},
          {"raw_bytes", raw},
          {"ratio", compression_ratio(raw, v.size)}};
}

// {"head_length": H, "prefixes": [{"version": k, "end": E_k, "sha256": S_k}, ...]}: in this file,
// bytes [H, E_k) are the sections of versions 1..k (the .btfdb appends each version's sections
// after those of the versions before, byte for byte; docs/format.md), S_k their sha256; so the
// sections that version k added are [E_(k-1), E_k) (E_0 = H).
json compute_layout(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  std::vector<uint8_t> head(kHeaderBytes);
  if (!in.read(reinterpret_cast<char*>(head.data()), std::streamsize(head.size()))) return nullptr;
  const uint64_t length = head_length(head.data(), head.size());
  if (length < kHeaderBytes || length > (uint64_t(256) << 20)) return nullptr;
  head.resize(size_t(length));
  if (!in.read(reinterpret_cast<char*>(head.data() + kHeaderBytes), std::streamsize(length - kHeaderBytes)))
    return nullptr;
  const DatabaseHead h = parse_head(head.data(), head.size(), file.string());
  std::vector<uint64_t> end(size_t(h.version) + 1, h.head_length);
  for (const auto& s : h.sections) end[s.version] = std::max(end[s.version], s.offset + s.length);
  for (size_t k = 1; k < end.size(); ++k) end[k] = std::max(end[k], end[k - 1]);
  Sha256 sha;
  std::vector<char> buffer(1 << 16);
  uint64_t at = h.head_length;
  json prefixes = json::array();
  for (size_t k = 1; k < end.size(); ++k) {
    while (at < end[k]) {
      const size_t n = size_t(std::min<uint64_t>(buffer.size(), end[k] - at));
      if (!in.read(buffer.data(), std::streamsize(n))) return nullptr;
      sha.update(buffer.data(), n);
      at += n;
    }
    Sha256 copy = sha;  // hex() finishes the hash it is called on
    prefixes.push_back({{"version", k}, {"end", end[k]}, {"sha256", copy.hex()}});
  }
  return {{"head_length", h.head_length}, {"prefixes", prefixes}};
}

}  // namespace

Catalogue::Catalogue(Store& store, DataDir data) : store_(store), data_(std::move(data)) {}

json Catalogue::databases() {
  json out = json::array();
  for (const auto& name : store_.database_names()) {
    const auto versions = store_.versions(name);
    json newest = version_json(versions.back());
    out.push_back({{"name", name},
                   {"versions", versions.size()},
                   {"version", newest["version"]},
                   {"size", newest["size"]},
                   {"sha256", newest["sha256"]},
                   {"materials", newest["materials"].size()},
                   {"raw_bytes", newest["raw_bytes"]},
                   {"ratio", newest["ratio"]},
                   {"updated", newest["created"]}});
  }
  return out;
}

json Catalogue::database(const std::string& name) {
  const auto versions = store_.versions(name);
  if (versions.empty()) throw NotFoundError("no database '" + name + "'");
  json all = json::array();
  for (const auto& v : versions) {
    all.push_back(version_json(v));
    all.back()["layout"] = layout(data_.root() / v.path);
  }
  return {{"name", name}, {"newest", all.back()}, {"versions", all}};
}

ContentInfo Catalogue::content(const std::string& name, std::optional<int64_t> version) {
  const auto versions = store_.versions(name);
  if (versions.empty()) throw NotFoundError("no database '" + name + "'");
  const VersionRecord* v = &versions.back();
  if (version) {
    auto it = std::find_if(versions.begin(), versions.end(), [&](const auto& r) { return r.version == *version; });
    if (it == versions.end()) throw NotFoundError("database '" + name + "' has no version " + std::to_string(*version));
    v = &*it;
  }
  return {name, v->version, data_.root() / v->path, v->size, v->sha256};
}

std::vector<uint8_t> Catalogue::preview(const std::string& database, const std::string& material,
                                        const PreviewOptions& options) {
  const auto db = open_cached(content(database, std::nullopt).path);
  const BtfMaterial m = db->material(material);
  return render_preview_png(db->decoder(), m.index(), options);
}

std::shared_ptr<const BtfDatabase> Catalogue::open_cached(const fs::path& file) {
  {
    std::lock_guard lock(preview_mutex_);
    if (auto it = preview_cache_.find(file); it != preview_cache_.end()) return it->second;
  }
  auto db = std::make_shared<const BtfDatabase>(BtfDatabase::open(file.string()));  // not under the lock: slow
  std::lock_guard lock(preview_mutex_);
  if (preview_cache_.size() >= 4) preview_cache_.clear();
  preview_cache_[file] = db;
  return db;
}

json Catalogue::layout(const fs::path& file) {
  {
    std::lock_guard lock(layout_mutex_);
    if (auto it = layout_cache_.find(file); it != layout_cache_.end()) return it->second;
  }
  json l;
  try {
    l = compute_layout(file);  // not under the lock: reads the whole file
  } catch (const std::exception& e) {
    spdlog::debug("no layout for {}: {}", file.string(), e.what());
    l = nullptr;
  }
  std::lock_guard lock(layout_mutex_);
  layout_cache_[file] = l;
  return l;
}

NextVersion Catalogue::next_version(const std::string& database) {
  const auto versions = store_.versions(database);
  NextVersion next;
  next.record.database = database;
  next.record.version = versions.empty() ? 1 : versions.back().version + 1;
  next.record.path = DataDir::version(database, next.record.version);
  next.record.materials = versions.empty() ? json::array() : versions.back().materials;
  next.file = data_.root() / next.record.path;
  if (!versions.empty()) next.previous_file = (data_.root() / versions.back().path).string();
  for (const auto& m : next.record.materials) next.existing.push_back(m.value("name", ""));
  return next;
}

VersionRecord Catalogue::describe(VersionRecord v, const std::string& job,
                                  const std::vector<MaterialRecord>& added) const {
  const fs::path file = data_.root() / v.path;
  v.sha256 = sha256_file(file.string());
  v.size = fs::file_size(file);
  for (const auto& m : added)
    v.materials.push_back({{"name", m.name},
                           {"raw_bytes", m.raw_bytes},
                           {"width", m.width},
                           {"height", m.height},
                           {"job", job},
                           {"version_added", v.version},
                           {"report", m.report}});
  v.job = job;
  v.created = now_seconds();
  return v;
}

void Catalogue::remove_unlisted() {
  std::set<std::string> listed;
  for (const auto& p : store_.all_version_paths()) listed.insert((data_.root() / p).lexically_normal().string());
  for (const auto& entry : fs::recursive_directory_iterator(data_.databases())) {
    if (!entry.is_regular_file() || listed.count(entry.path().lexically_normal().string())) continue;
    spdlog::warn("removing unlisted file {}", entry.path().string());
    fs::remove(entry.path());
  }
}

}  // namespace btfvq::server
