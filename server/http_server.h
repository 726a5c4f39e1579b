#pragma once
// The HTTP shell over the Service: REST routes under /v1 (docs/api.md), bearer-token check, and
// the one mapping from btfvq::Error subclasses to status codes and JSON error bodies.
#include <atomic>
#include <memory>
#include <string>
#include <thread>

#include "server/service.h"

namespace httplib {
class Server;
}

namespace btfvq::server {

struct HttpOptions {
  std::string token;                    // empty: no authentication
  uint64_t max_request_bytes = 1 << 20;  // JSON bodies (POST /v1/jobs)
  int threads = 16;                     // concurrent connections (event streams hold one each)
};

class HttpServer {
 public:
  HttpServer(Service& service, HttpOptions options);
  ~HttpServer();

  // Binds HOST:PORT (PORT 0 = any free port) and returns the port. Throws Error on failure.
  int bind(const std::string& host, int port);
  // Serves until stop(). run_in_background() does the same on its own thread.
  void run();
  void run_in_background();
  void stop();

 private:
  void install_routes();
  Service& service_;
  HttpOptions options_;
  std::unique_ptr<httplib::Server> server_;
  std::thread thread_;
  std::atomic<bool> stopping_{false};
};

// Maps an exception to (status, {"error": {"code", "message"}}). Exposed for tests.
std::pair<int, std::string> error_response(std::exception_ptr error);

}  // namespace btfvq::server
