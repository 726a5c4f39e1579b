#pragma once
// How btfvq-server holds its connections (docs/api.md, "Connections"). cpp-httplib serves each
// connection on one thread from accept to close, so a client that opens a connection and sends
// nothing (or a byte now and then) holds a thread for as long as it likes: the per-read timeout
// never fires. Here each connection must finish its request line and headers within a deadline,
// its body at a minimum average rate, and the connections open at once are capped per client
// address and in total (503 with Retry-After beyond), so that the bounded pool of threads is never
// all held by clients that do not send.
#include <atomic>
#include <cstdint>
#include <memory>

namespace httplib {
class Server;
}

namespace btfvq::server {

struct ConnectionLimits {
  int max_connections = 512;           // open at once in total; each holds one thread while open
  int max_connections_per_client = 32;  // open at once from one remote address
  int header_timeout_s = 10;            // request line and headers, from connect (or first byte when kept alive)
  int body_min_bytes_per_s = 16384;     // average rate of a body, after a grace of header_timeout_s
  int retry_after_s = 5;                // Retry-After of the 503 beyond a cap
  int idle_timeout_s = 5;               // a kept-alive connection waiting for its next request
  int read_timeout_s = 60;              // any one read or write
};

// What the connections did since the start, for /metrics: an attack shows as refusals and timeouts.
struct ConnectionCounts {
  std::atomic<int64_t> open{0};
  std::atomic<uint64_t> refused{0}, timed_out{0};
};

// A cpp-httplib server whose task queue is the one pool of threads (at most max_connections plus a
// few that answer the 503s) and whose connections keep to `limits`. `counts` must outlive it.
std::unique_ptr<httplib::Server> make_limited_server(const ConnectionLimits& limits, ConnectionCounts& counts);

}  // namespace btfvq::server
