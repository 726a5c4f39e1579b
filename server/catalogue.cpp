#include "server/catalogue.h"

#include <spdlog/spdlog.h>

#include <algorithm>
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
  for (const auto& v : versions) all.push_back(version_json(v));
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
