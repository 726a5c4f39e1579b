#pragma once
// btfvq-server's configuration: configs/server.json (embedded defaults), an optional --config
// file on top, then command-line flags and BTFVQ_TOKEN. Unknown keys are errors.
#include <optional>
#include <string>

#include "server/http_server.h"
#include "server/service.h"
#include "server/slurm_executor.h"

namespace btfvq::server {

struct ServerConfig {
  std::string host = "127.0.0.1";
  int port = 8080;
  ServiceConfig service;
  HttpOptions http;
  std::string log_level = "info";
  std::string executor = "local";  // "local" (worker threads) or "slurm" (phase 3 on a cluster)
  SlurmSettings slurm;
};

struct ServerFlags {
  std::optional<std::string> config_file, listen, data_dir, input_root;
  std::optional<int> workers;
};

// Parses "HOST:PORT" (PORT 0..65535); throws ConfigError naming `what`.
std::pair<std::string, int> parse_listen(const std::string& value, const std::string& what);

ServerConfig load_server_config(const ServerFlags& flags);

}  // namespace btfvq::server
