#pragma once
// The HTTP shell over the Service: REST routes under /v1 (docs/api.md), each a line or two over
// the helpers of http_requests.h and http_responses.h, behind the bearer-token check; errors reach
// the client through http_errors.h.
#include <atomic>
#include <memory>
#include <string>
#include <thread>

#include "server/http_connections.h"
#include "server/service.h"

namespace httplib {
class Server;
}

namespace btfvq::server {

struct HttpOptions {
  std::string token;                    // empty: no authentication
  uint64_t max_request_bytes = 1 << 20;  // JSON bodies (POST /v1/jobs)
  ConnectionLimits connections;         // open connections and their deadlines (event streams hold one each)
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
  void install_handlers();  // errors and authentication, around every route
  void install_routes();
  Service& service_;
  HttpOptions options_;
  ConnectionCounts connections_;  // before server_, which counts into it
  std::unique_ptr<httplib::Server> server_;
  std::thread thread_;
  std::atomic<bool> stopping_{false};
};

}  // namespace btfvq::server
