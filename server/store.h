#pragma once
// Durable state of the server: jobs, uploads and the database catalogue, in SQLite (WAL mode).
// Blobs live in the data directory; the store records only complete ones (path, size, sha256).
// All methods are thread-safe (one connection behind a mutex: the store is never the bottleneck).
#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdint>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "server/job_state.h"

struct sqlite3;

namespace btfvq::server {

// The clock of the records' timestamps: unix seconds.
inline double now_seconds() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

struct JobRecord {
  std::string id;
  int64_t seq = 0;                  // submission order (assigned by the store)
  std::string database;
  nlohmann::json spec;              // the validated request
  JobState state = JobState::queued;
  nlohmann::json progress = nlohmann::json::object();
  nlohmann::json error;             // null or {"code", "message"}
  double created = 0, started = 0, finished = 0;  // unix seconds; 0 = not yet
  int64_t version = 0;              // the version it published (succeeded only)
};

struct UploadRecord {
  std::string id;
  uint64_t size = 0;
  std::string sha256;
  std::string state = "complete";
  double created = 0;
};

struct VersionRecord {
  std::string database;
  int64_t version = 0;
  std::string path;          // relative to the data directory
  std::string sha256;
  uint64_t size = 0;
  nlohmann::json materials;  // [{"name", "raw_bytes", "width", "height", "job"}]
  std::string job;
  double created = 0;
};

class Store {
 public:
  explicit Store(const std::string& sqlite_path);
  ~Store();
  Store(const Store&) = delete;
  Store& operator=(const Store&) = delete;

  // Jobs.
  int64_t insert_job(const JobRecord& job);  // returns seq
  std::optional<JobRecord> job(const std::string& id);
  std::vector<JobRecord> jobs();  // in submission order
  std::vector<JobRecord> jobs_in_state(JobState state);
  void set_job_state(const std::string& id, JobState state, const nlohmann::json& error,
                     double started, double finished);
  void set_job_progress(const std::string& id, const nlohmann::json& progress);
  // Recovery: every 'running' job goes back to 'queued'; returns their ids.
  std::vector<std::string> requeue_running();

  // Uploads (only complete uploads are stored).
  void insert_upload(const UploadRecord& upload);
  std::optional<UploadRecord> upload(const std::string& id);
  std::vector<UploadRecord> uploads();

  // Catalogue. publish() adds the version and marks its job succeeded in one transaction.
  void publish(const VersionRecord& version, double finished);
  std::vector<VersionRecord> versions(const std::string& database);  // oldest first
  std::vector<std::string> database_names();
  std::vector<std::string> all_version_paths();

 private:
  void exec(const std::string& sql);
  sqlite3* db_ = nullptr;
  std::mutex mutex_;
};

}  // namespace btfvq::server
