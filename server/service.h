#pragma once
// The server's service layer: validated job submission, the per-database job queue and its
// workers, streamed uploads, the catalogue of published database versions, and metrics. It knows
// nothing about HTTP (routes.cpp is a thin shell over it) and nothing about compression (the
// Executor does the work). Durable state lives in the Store; blobs in the data directory:
//   <data>/btfvq.sqlite            jobs, uploads, versions
//   <data>/uploads/<id>.upload     complete uploads
//   <data>/databases/<name>/v<N>.btfdb  published versions
// Each file is written under a hidden temporary name beside it (pipeline/util/atomic_file.h).
#include <nlohmann/json.hpp>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "pipeline/decode/preview.h"
#include <btfvq/renderer_api.h>
#include "pipeline/util/atomic_file.h"
#include "pipeline/util/sha256.h"
#include "server/executor.h"
#include "server/store.h"

namespace btfvq::server {

struct ServiceConfig {
  std::filesystem::path data_dir;
  std::filesystem::path input_root;               // empty: server-side input paths are refused
  uint64_t max_upload_bytes = uint64_t(4) << 30;
  uint64_t max_expanded_bytes = uint64_t(16) << 30;
  int workers = 1;
};

// A published, complete database file.
struct ContentInfo {
  std::string database;
  int64_t version = 0;
  std::filesystem::path path;
  uint64_t size = 0;
  std::string sha256;
};

class Service;

// One upload being streamed to the temporary of an AtomicFile, so that an upload destroyed
// without finish() (a broken connection, a bad checksum) leaves nothing behind.
class UploadSink {
 public:
  ~UploadSink();
  // Appends bytes; returns false (and sets too_large()) once the size limit would be exceeded.
  bool write(const char* data, size_t size);
  bool too_large() const { return too_large_; }
  // Verifies `expected_sha256` (if not empty), commits the file and records the upload.
  nlohmann::json finish(const std::string& expected_sha256);

 private:
  friend class Service;
  UploadSink(Service& service, std::string id);
  Service& service_;
  std::string id_;
  AtomicFile file_;
  std::ofstream out_;  // after file_: closed before the temporary is removed
  Sha256 hash_;
  uint64_t size_ = 0;
  bool too_large_ = false, done_ = false;
  std::shared_ptr<std::atomic<uint64_t>> progress_;
};

class Service {
 public:
  Service(ServiceConfig config, Executor executor);
  ~Service();

  // Recovery (re-queue interrupted jobs, remove temporary and unlisted files), then the workers.
  void start();
  // Stops the workers; running jobs are interrupted and go back to 'queued' for the next start.
  void stop();

  // Jobs. submit() validates everything (400 naming the field, 403 for paths outside the input
  // root) before it changes any state.
  nlohmann::json submit(const nlohmann::json& request);
  nlohmann::json job(const std::string& id);
  nlohmann::json jobs();
  nlohmann::json cancel(const std::string& id);

  // Change notification for event streams: blocks until something changed after `revision` or
  // `timeout` passed; returns the current revision.
  uint64_t wait_for_change(uint64_t revision, std::chrono::milliseconds timeout);
  uint64_t revision();
  bool stopping() const { return stopping_; }

  // Uploads. `declared_size` (Content-Length) lets an oversized upload fail before any byte is read.
  std::unique_ptr<UploadSink> begin_upload(const std::string& id, std::optional<uint64_t> declared_size);
  nlohmann::json upload(const std::string& id);

  // Catalogue.
  nlohmann::json databases();
  nlohmann::json database(const std::string& name);
  ContentInfo content(const std::string& name, std::optional<int64_t> version);
  // PNG preview (pipeline/decode/preview.h) of a material of the latest version of a database.
  std::vector<uint8_t> preview(const std::string& database, const std::string& material, const PreviewOptions& options);

  void count_bytes_served(uint64_t n) { bytes_served_ += n; }
  std::string metrics();
  const ServiceConfig& config() const { return config_; }

 private:
  friend class UploadSink;
  struct Live {
    nlohmann::json progress = nlohmann::json::object();
    bool cancel_requested = false;
    std::string stage;
    double stage_started = 0;
    double last_persisted = 0;
  };

  void recover();
  void worker_loop();
  std::optional<JobRecord> next_job();  // under mutex_
  void run(const JobRecord& job);
  void publish(const JobRecord& job, const JobSpec& spec, VersionRecord version,
               const std::vector<MaterialRecord>& added);
  void on_progress(const std::string& id, const JobProgress& p);
  void finish_stage(Live& live, double now);
  void notify();  // under mutex_
  JobSpec parse_spec(const JobRecord& job) const;
  nlohmann::json validate_request(const nlohmann::json& request, const std::string& id);
  void check_sample(const std::filesystem::path& file, const std::string& field) const;
  std::filesystem::path resolve_input_path(const std::string& given, const std::string& field) const;
  nlohmann::json job_json(const JobRecord& job);  // under mutex_
  std::filesystem::path upload_path(const std::string& id) const;

  ServiceConfig config_;
  Executor executor_;
  std::unique_ptr<Store> store_;
  std::mutex mutex_;
  std::condition_variable work_cv_, change_cv_;
  std::vector<std::thread> workers_;
  std::set<std::string> busy_databases_;
  std::map<std::string, Live> live_;
  std::map<std::string, std::shared_ptr<std::atomic<uint64_t>>> uploading_;
  std::atomic<bool> stopping_{false};
  bool started_ = false;
  uint64_t revision_ = 0;
  std::atomic<uint64_t> bytes_served_{0}, bytes_uploaded_{0};
  std::map<std::string, double> stage_seconds_;
  // Opened databases for previews, by file (a published version never changes); a few at most.
  std::mutex preview_mutex_;
  std::map<std::filesystem::path, std::shared_ptr<const BtfDatabase>> preview_cache_;
};

}  // namespace btfvq::server
