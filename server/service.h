#pragma once
// The server's service layer, the facade that the routes call: job submission and the job queue
// (jobs.h, with the request schema in job_request.h), streamed uploads (uploads.h), the catalogue
// of published database versions (catalogue.h) and the metrics (metrics_text.h). It knows nothing
// about HTTP (routes.cpp is a thin shell over it) and nothing about compression (the Executor does
// the work). Durable state lives in the Store; blobs in the data directory (data_dir.h).
#include <nlohmann/json.hpp>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "server/catalogue.h"
#include "server/data_dir.h"
#include "server/executor.h"
#include "server/job_request.h"
#include "server/jobs.h"
#include "server/store.h"
#include "server/uploads.h"

namespace btfvq::server {

struct ServiceConfig {
  std::filesystem::path data_dir;
  std::filesystem::path input_root;               // empty: server-side input paths are refused
  uint64_t max_upload_bytes = uint64_t(4) << 30;
  uint64_t max_expanded_bytes = uint64_t(16) << 30;
  int workers = 1;
  // A resumable upload that receives no piece for this long is removed (upload_abandon_after_s).
  double upload_abandon_after_s = 86400;
};

class Service {
 public:
  Service(ServiceConfig config, Executor executor);
  ~Service();

  // Recovery (re-queue interrupted jobs, remove temporary and unlisted files), then the workers.
  void start();
  // Stops the workers; running jobs are interrupted and go back to 'queued' for the next start.
  void stop() { jobs_.stop(); }

  // Jobs. submit() validates everything (400 naming the field, 403 for paths outside the input
  // root) before it changes any state.
  nlohmann::json submit(const nlohmann::json& request) { return jobs_.submit(request); }
  nlohmann::json job(const std::string& id) { return jobs_.job(id); }
  nlohmann::json jobs() { return jobs_.jobs(); }
  nlohmann::json cancel(const std::string& id) { return jobs_.cancel(id); }

  // Change notification for event streams (JobQueue::wait_for_change).
  uint64_t wait_for_change(uint64_t revision, std::chrono::milliseconds timeout) {
    return jobs_.wait_for_change(revision, timeout);
  }
  uint64_t revision() { return jobs_.revision(); }
  bool stopping() const { return jobs_.stopping(); }

  std::unique_ptr<UploadSink> begin_upload(const std::string& id, const UploadRequest& request) {
    return uploads_.begin(id, request);
  }
  nlohmann::json upload(const std::string& id) { return uploads_.info(id); }

  nlohmann::json databases() { return catalogue_.databases(); }
  nlohmann::json database(const std::string& name) { return catalogue_.database(name); }
  ContentInfo content(const std::string& name, std::optional<int64_t> version) {
    return catalogue_.content(name, version);
  }
  std::vector<uint8_t> preview(const std::string& database, const std::string& material,
                               const PreviewOptions& options) {
    return catalogue_.preview(database, material, options);
  }

  void count_bytes_served(uint64_t n) { bytes_served_ += n; }
  std::string metrics();
  const ServiceConfig& config() const { return config_; }

 private:
  static ServiceConfig prepared(ServiceConfig config);

  ServiceConfig config_;
  DataDir data_;
  Store store_;
  Uploads uploads_;
  Catalogue catalogue_;
  JobRequests requests_;
  JobQueue jobs_;
  std::atomic<uint64_t> bytes_served_{0};
  bool started_ = false;
};

}  // namespace btfvq::server
