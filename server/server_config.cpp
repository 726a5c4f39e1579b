#include "server/server_config.h"

#include <cstdlib>

#include "pipeline/util/config.h"
#include <btfvq/error.h>
#include "server/numbers.h"

namespace btfvq::server {

std::pair<std::string, int> parse_listen(const std::string& value, const std::string& what) {
  const auto colon = value.rfind(':');
  if (colon == std::string::npos || colon == 0)
    throw ConfigError(what + ": '" + value + "' is not HOST:PORT");
  const std::string port = value.substr(colon + 1);
  const auto n = whole_integer(port);
  if (!n || *n < 0 || *n > 65535) throw ConfigError(what + ": port '" + port + "' is not in 0..65535");
  return {value.substr(0, colon), int(*n)};
}

ServerConfig load_server_config(const ServerFlags& flags) {
  auto d = ParameterDictionary::embedded_default("server");
  if (flags.config_file) d.merge(ParameterDictionary::load_file(*flags.config_file));
  ServerConfig c;
  std::tie(c.host, c.port) = parse_listen(d.string("listen"), d.origin() + ": listen");
  c.service.data_dir = d.string("data_dir");
  c.service.workers = d.integer("workers", 1, 64);
  c.service.input_root = d.string("input_root");
  c.service.max_upload_bytes = uint64_t(d.number("max_upload_bytes", 1, 1e15));
  c.service.max_expanded_bytes = uint64_t(d.number("max_expanded_bytes", 1, 1e16));
  c.service.upload_abandon_after_s = double(d.integer("upload_abandon_after_s", 1, 366 * 86400));
  c.http.max_request_bytes = uint64_t(d.number("max_request_bytes", 1024, 1 << 30));
  auto& k = c.http.connections;
  // A config written before the connection limits names the old fixed pool: say what replaced it
  // rather than only that the key is unknown.
  if (d.has("http_threads"))
    throw ConfigError(d.origin() + ": http_threads is no longer a setting: the pool of HTTP threads grows on demand "
                      "up to http_max_connections (docs/api.md \"Connections\"); remove the key");
  // The Debian cpp-httplib waits with select(), which cannot watch a socket numbered 1024 or more.
  k.max_connections = d.integer("http_max_connections", 2, 900);
  k.max_connections_per_client = d.integer("http_max_connections_per_client", 1, k.max_connections);
  k.header_timeout_s = d.integer("http_header_timeout_s", 1, 3600);
  k.body_min_bytes_per_s = d.integer("http_body_min_bytes_per_s", 1, 1 << 30);
  k.retry_after_s = d.integer("http_retry_after_s", 1, 3600);
  k.idle_timeout_s = d.integer("http_idle_timeout_s", 1, 3600);
  c.http.token = d.string("token");
  c.log_level = d.string("log_level");
  c.executor = d.string("executor");
  if (c.executor != "local" && c.executor != "slurm")
    throw ConfigError(d.origin() + ": executor '" + c.executor + "' must be \"local\" or \"slurm\"");
  c.slurm.partition = d.string("slurm.partition");
  c.slurm.shared_folder = d.string("slurm.shared_folder");
  c.slurm.sbatch_options = d.string("slurm.sbatch_options");
  c.slurm.tile_command = d.string("slurm.tile_command");
  c.slurm.tiles_per_element = d.integer("slurm.tiles_per_element", 1, 1 << 20);
  c.slurm.cpus_per_element = d.integer("slurm.cpus_per_element", 0, 1024);
  c.slurm.max_resubmits = d.integer("slurm.max_resubmits", 0, 100);
  c.slurm.poll_interval_s = d.number("slurm.poll_interval_s", 0.05, 600);
  if (c.executor == "slurm" && c.slurm.shared_folder.empty())
    throw ConfigError(d.origin() + ": executor \"slurm\" needs slurm.shared_folder (a folder every node sees)");
  d.check_unused();

  if (flags.listen) std::tie(c.host, c.port) = parse_listen(*flags.listen, "--listen");
  if (flags.data_dir) c.service.data_dir = *flags.data_dir;
  if (flags.input_root) c.service.input_root = *flags.input_root;
  if (flags.workers) {
    if (*flags.workers < 1 || *flags.workers > 64) throw ConfigError("--workers must be in 1..64");
    c.service.workers = *flags.workers;
  }
  if (const char* token = std::getenv("BTFVQ_TOKEN"); token && *token) c.http.token = token;
  if (c.service.data_dir.empty()) throw ConfigError("data_dir must not be empty");
  return c;
}

}  // namespace btfvq::server
