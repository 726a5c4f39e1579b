#pragma once
// GET /metrics: the Prometheus text format (version 0.0.4) of one snapshot of the service's numbers.
#include <cstdint>
#include <map>
#include <string>

#include "server/job_state.h"

namespace btfvq::server {

struct MetricsSnapshot {
  std::map<JobState, int> jobs;  // by state; a state with no job may be missing
  int workers = 0;
  uint64_t bytes_served = 0, bytes_uploaded = 0;
  size_t databases = 0;
  std::map<std::string, double> stage_seconds;
};

std::string metrics_text(const MetricsSnapshot& m);

struct ConnectionCounts;  // http_connections.h
std::string connection_metrics_text(const ConnectionCounts& c);

}  // namespace btfvq::server
