#include "server/service.h"

#include <spdlog/spdlog.h>

#include <btfvq/error.h>
#include "server/metrics_text.h"

namespace btfvq::server {
namespace fs = std::filesystem;

// Checked and made ready before the store opens in it.
ServiceConfig Service::prepared(ServiceConfig config) {
  if (config.workers < 1) throw ConfigError("workers must be at least 1");
  if (!(config.upload_abandon_after_s > 0)) throw ConfigError("upload_abandon_after_s must be positive");
  const DataDir data(config.data_dir);
  fs::create_directories(data.uploads());
  fs::create_directories(data.partial_uploads());
  fs::create_directories(data.databases());
  if (!config.input_root.empty()) {
    std::error_code ec;
    config.input_root = fs::canonical(config.input_root, ec);
    if (ec) throw ConfigError("input_root '" + config.input_root.string() + "' does not exist");
  }
  return config;
}

Service::Service(ServiceConfig config, Executor executor)
    : config_(prepared(std::move(config))),
      data_(config_.data_dir),
      store_(data_.store().string()),
      uploads_(store_, data_, config_.max_upload_bytes),
      catalogue_(store_, data_),
      requests_(store_, data_, config_.input_root, config_.max_expanded_bytes),
      jobs_(store_, data_, catalogue_, requests_, std::move(executor), config_.max_expanded_bytes) {}

Service::~Service() { stop(); }

void Service::start() {
  if (started_) return;
  jobs_.requeue_interrupted();
  // Anything in the data directory that the store does not list is a leftover of a crash.
  catalogue_.remove_unlisted();
  uploads_.remove_unlisted();
  started_ = true;
  // Abandoned uploads are swept by a worker between jobs (no thread of their own), every half of the
  // abandon time but at least once a minute: one is gone that much after it is due, unless every
  // worker is busy with a job then.
  const std::chrono::duration<double> abandon(config_.upload_abandon_after_s);
  jobs_.set_maintenance([this, abandon] { uploads_.remove_abandoned(abandon); },
                        std::chrono::duration_cast<std::chrono::milliseconds>(
                            std::min<std::chrono::duration<double>>(abandon / 2, std::chrono::seconds(60))));
  jobs_.start(config_.workers);
  spdlog::info("service started: data {}, {} worker(s)", config_.data_dir.string(), config_.workers);
}

std::string Service::metrics() {
  MetricsSnapshot m;
  for (const auto& j : store_.jobs()) ++m.jobs[j.state];
  m.workers = config_.workers;
  m.bytes_served = bytes_served_;
  m.bytes_uploaded = uploads_.bytes_received();
  m.databases = store_.database_names().size();
  m.stage_seconds = jobs_.stage_seconds();
  return metrics_text(m);
}

}  // namespace btfvq::server
