#pragma once
// The catalogue of published database versions: the listings, downloads and previews of what the
// store records, and the numbering and description of the version a job publishes.
#include <nlohmann/json.hpp>

#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "pipeline/decode/preview.h"
#include <btfvq/renderer_api.h>
#include "server/data_dir.h"
#include "server/executor.h"
#include "server/store.h"

namespace btfvq::server {

// A published, complete database file.
struct ContentInfo {
  std::string database;
  int64_t version = 0;
  std::filesystem::path path;
  uint64_t size = 0;
  std::string sha256;
};

// The version that a job of a database will publish, decided before the job runs.
struct NextVersion {
  VersionRecord record;                // number, relative path and the materials it inherits
  std::filesystem::path file;          // where the executor writes it
  std::string previous_file;           // the newest version's file to build on; empty for the first
  std::vector<std::string> existing;   // the names of the inherited materials
};

class Catalogue {
 public:
  Catalogue(Store& store, DataDir data);

  nlohmann::json databases();
  nlohmann::json database(const std::string& name);
  ContentInfo content(const std::string& name, std::optional<int64_t> version);
  // PNG preview (pipeline/decode/preview.h) of a material of the newest version of a database.
  std::vector<uint8_t> preview(const std::string& database, const std::string& material, const PreviewOptions& options);

  NextVersion next_version(const std::string& database);
  // `next` as the store records it once its job wrote the file: hashed, with the materials added.
  VersionRecord describe(VersionRecord next, const std::string& job, const std::vector<MaterialRecord>& added) const;
  // At startup: removes every file under databases/ that the store does not list.
  void remove_unlisted();

 private:
  std::shared_ptr<const BtfDatabase> open_cached(const std::filesystem::path& file);
  // The byte layout of a published version's file for delta downloads (docs/api.md "Delta
  // downloads"), computed once per file (a published version never changes); null for a file that
  // is not a .btfdb.
  nlohmann::json layout(const std::filesystem::path& file);

  Store& store_;
  DataDir data_;
  // Opened databases for previews, by file (a published version never changes); a few at most.
  std::mutex preview_mutex_;
  std::map<std::filesystem::path, std::shared_ptr<const BtfDatabase>> preview_cache_;
  std::mutex layout_mutex_;
  std::map<std::filesystem::path, nlohmann::json> layout_cache_;
};

}  // namespace btfvq::server
