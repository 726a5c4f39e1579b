#include "server/http_connections.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

#include <httplib.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <map>
#include <mutex>
#include <optional>
#include <string_view>
#include <system_error>
#include <thread>
#include <vector>

#include "server/errors.h"
#include "server/http_errors.h"

namespace btfvq::server {
namespace {
using Clock = std::chrono::steady_clock;

// Threads beyond max_connections: a rejected connection is answered on one of these, so that the
// 503 goes out even while every admitted connection holds its thread.
constexpr size_t kSpareThreads = 8;
// The longest a wait blocks before it looks again whether the server is stopping.
constexpr auto kStopCheck = std::chrono::milliseconds(200);

// The server's one pool: it grows on demand up to its bound and keeps its threads until shutdown,
// so the thread count never exceeds the bound however many connections arrive.
class ConnectionPool final : public httplib::TaskQueue {
 public:
  explicit ConnectionPool(size_t max_threads) : max_threads_(max_threads) {}

  void enqueue(std::function<void()> fn) override {
    std::lock_guard lock(mutex_);
    jobs_.push_back(std::move(fn));
    if (jobs_.size() > idle_ && threads_.size() < max_threads_) {
      try {
        threads_.emplace_back([this] { work(); });
      } catch (const std::system_error& e) {
        // Out of threads (ulimit, memory): the connection waits for one of the threads there are.
        spdlog::warn("http: cannot start a thread beyond {}: {}", threads_.size(), e.what());
      }
    }
    cv_.notify_one();
  }

  void shutdown() override {
    {
      std::lock_guard lock(mutex_);
      shutdown_ = true;
    }
    cv_.notify_all();
    for (auto& t : threads_) t.join();  // enqueue() is not called once httplib shuts the queue down
  }

 private:
  void work() {
    for (;;) {
      std::function<void()> fn;
      {
        std::unique_lock lock(mutex_);
        ++idle_;
        cv_.wait(lock, [&] { return !jobs_.empty() || shutdown_; });
        --idle_;
        if (jobs_.empty()) return;
        fn = std::move(jobs_.front());
        jobs_.pop_front();
      }
      fn();
    }
  }

  const size_t max_threads_;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> jobs_;
  std::vector<std::thread> threads_;
  size_t idle_ = 0;
  bool shutdown_ = false;
};

// Counts the open connections per remote address and in total.
class ConnectionGate {
 public:
  explicit ConnectionGate(const ConnectionLimits& limits) : limits_(limits) {}

  // Why `address` may not open one more connection, or nothing (and the connection is counted).
  std::optional<std::string> admit(const std::string& address) {
    std::lock_guard lock(mutex_);
    if (total_ >= limits_.max_connections)
      return "the server has " + std::to_string(total_) + " connections open, its limit";
    int& mine = per_address_[address];
    if (mine >= limits_.max_connections_per_client)
      return std::to_string(mine) + " connections are open from " + address + ", the limit per client";
    ++mine;
    ++total_;
    return std::nullopt;
  }

  void release(const std::string& address) {
    std::lock_guard lock(mutex_);
    --total_;
    if (--per_address_[address] == 0) per_address_.erase(address);
  }

 private:
  const ConnectionLimits limits_;
  std::mutex mutex_;
  std::map<std::string, int> per_address_;
  int total_ = 0;
};

std::string address_text(const sockaddr_storage& a, int* port) {
  char text[INET6_ADDRSTRLEN] = "";
  if (a.ss_family == AF_INET) {
    const auto& v4 = reinterpret_cast<const sockaddr_in&>(a);
    inet_ntop(AF_INET, &v4.sin_addr, text, sizeof text);
    if (port) *port = ntohs(v4.sin_port);
  } else if (a.ss_family == AF_INET6) {
    const auto& v6 = reinterpret_cast<const sockaddr_in6&>(a);
    inet_ntop(AF_INET6, &v6.sin6_addr, text, sizeof text);
    if (port) *port = ntohs(v6.sin6_port);
  }
  return text;
}

std::string peer_address(int fd, int* port = nullptr) {
  sockaddr_storage a{};
  socklen_t n = sizeof a;
  return getpeername(fd, reinterpret_cast<sockaddr*>(&a), &n) == 0 ? address_text(a, port) : std::string();
}

// A whole response written past httplib, for the two answers that come from the connection rather
// than from a route: the status and body still come from error_response() (http_errors.h).
std::string raw_response(const Error& error, const std::string& extra_headers) {
  const auto [status, body] = error_response(std::make_exception_ptr(error));
  const char* reason = status == 408 ? "Request Timeout" : status == 503 ? "Service Unavailable" : "Error";
  return "HTTP/1.1 " + std::to_string(status) + " " + reason +
         "\r\nContent-Type: application/json\r\nContent-Length: " + std::to_string(body.size()) +
         "\r\nConnection: close\r\n" + extra_headers + "\r\n" + body;
}

// The socket under httplib's request parser, with deadlines: every read waits at most until the
// deadline of the phase it is in (headers, body, idle between requests), so that the total time a
// client may take is bounded, not only the time between two bytes.
class DeadlineStream final : public httplib::Stream {
 public:
  DeadlineStream(int fd, const ConnectionLimits& limits, const std::atomic<socket_t>& listener,
                 ConnectionCounts& counts)
      : fd_(fd), limits_(limits), listener_(listener), counts_(counts), accepted_(Clock::now()) {}

  // Waits for the first byte of the next request; false when the client closed, stayed silent
  // past its deadline or the server stops.
  bool next_request() {
    const bool first = requests_++ == 0;
    const auto until = first ? accepted_ + seconds(limits_.header_timeout_s) : Clock::now() + seconds(limits_.idle_timeout_s);
    if (pos_ == len_ && (!wait(POLLIN, until) || !fill())) return false;
    deadline_ = first ? until : Clock::now() + seconds(limits_.header_timeout_s);
    in_body_ = false;
    wrote_ = false;
    return true;
  }

  // The headers are in: from here on the body must keep to its minimum rate.
  void headers_received() {
    in_body_ = true;
    body_start_ = Clock::now();
    body_bytes_ = 0;
  }

  bool is_readable() const override { return pos_ < len_ || wait(POLLIN, read_deadline()); }
  bool is_writable() const override { return !dead_ && wait(POLLOUT, Clock::now() + seconds(limits_.read_timeout_s)); }

  ssize_t read(char* ptr, size_t size) override {
    if (dead_) return -1;
    if (pos_ == len_) {
      if (!wait(POLLIN, read_deadline())) {
        time_out();
        return -1;
      }
      if (!fill()) return -1;
    }
    const size_t n = std::min(size, len_ - pos_);
    std::copy_n(buffer_ + pos_, n, ptr);
    pos_ += n;
    if (in_body_) body_bytes_ += n;
    return ssize_t(n);
  }

  ssize_t write(const char* ptr, size_t size) override {
    if (!is_writable()) return -1;
    const ssize_t n = ::send(fd_, ptr, size, MSG_NOSIGNAL);
    // An interim "100 Continue" is not the answer: a body that is late after it still gets its 408.
    if (n > 0 && std::string_view(ptr, std::min<size_t>(size, 10)) != "HTTP/1.1 1") wrote_ = true;
    return n;
  }

  void get_remote_ip_and_port(std::string& ip, int& port) const override { ip = peer_address(fd_, &port); }
  void get_local_ip_and_port(std::string& ip, int& port) const override {
    sockaddr_storage a{};
    socklen_t n = sizeof a;
    ip = getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &n) == 0 ? address_text(a, &port) : std::string();
  }
  socket_t socket() const override { return fd_; }

 private:
  static std::chrono::seconds seconds(int s) { return std::chrono::seconds(s); }
  bool stopping() const { return listener_ == INVALID_SOCKET; }

  Clock::time_point read_deadline() const {
    auto until = deadline_;
    if (in_body_)
      until = body_start_ + seconds(limits_.header_timeout_s) +
              std::chrono::duration_cast<Clock::duration>(
                  std::chrono::duration<double>(double(body_bytes_) / limits_.body_min_bytes_per_s));
    return std::min(until, Clock::now() + seconds(limits_.read_timeout_s));
  }

  // True when the socket is ready for `events` before `until`; false on the deadline, an error or
  // the server stopping.
  bool wait(short events, Clock::time_point until) const {
    for (;;) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(until - Clock::now());
      if (left.count() <= 0 || stopping()) return false;
      pollfd p{fd_, events, 0};
      const int r = ::poll(&p, 1, int(std::min(left, std::chrono::milliseconds(kStopCheck)).count()));
      if (r > 0) return true;
      if (r < 0 && errno != EINTR) return false;
    }
  }

  bool fill() {
    const ssize_t n = ::recv(fd_, buffer_, sizeof buffer_, 0);
    if (n <= 0) return false;
    pos_ = 0;
    len_ = size_t(n);
    return true;
  }

  // A request that started but did not arrive in time gets a 408 (when nothing of a response went
  // out yet), and the connection is done either way.
  void time_out() {
    if (dead_ || stopping()) return;
    dead_ = true;
    ++counts_.timed_out;
    if (wrote_) return;
    const std::string what = in_body_ ? "the request body arrived slower than " +
                                            std::to_string(limits_.body_min_bytes_per_s) + " bytes/s"
                                      : "the request headers did not arrive within " +
                                            std::to_string(limits_.header_timeout_s) + " s";
    const std::string r = raw_response(RequestTimeoutError(what), "");
    ::send(fd_, r.data(), r.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
  }

  const int fd_;
  const ConnectionLimits& limits_;
  const std::atomic<socket_t>& listener_;  // closed by Server::stop()
  ConnectionCounts& counts_;
  const Clock::time_point accepted_;
  Clock::time_point deadline_, body_start_;
  bool in_body_ = false, wrote_ = false, dead_ = false;
  size_t body_bytes_ = 0;
  int requests_ = 0;
  char buffer_[4096];
  size_t pos_ = 0, len_ = 0;
};

class LimitedServer final : public httplib::Server {
 public:
  LimitedServer(const ConnectionLimits& limits, ConnectionCounts& counts)
      : limits_(limits), counts_(counts), gate_(limits) {
    const size_t threads = size_t(limits.max_connections) + kSpareThreads;
    // httplib calls this once per listen, after binding: the moment to widen its listen backlog of
    // 5, which drops the SYNs of a burst of connections and delays every client behind them by the
    // kernel's one-second retransmission.
    new_task_queue = [this, threads] {
      ::listen(svr_sock_, limits_.max_connections);
      return new ConnectionPool(threads);
    };
    set_read_timeout(limits.read_timeout_s);
    set_write_timeout(limits.read_timeout_s);
    set_keep_alive_timeout(limits.idle_timeout_s);  // what the Keep-Alive header announces
    // httplib writes a response's headers and body in separate sends; with Nagle's algorithm the
    // body waited for the ACK of the headers, which a kept-alive client delays by 40 ms: the soak
    // of bench/bench_soak.py measured p95 of 42 ms for /healthz (p50 1 ms) before this.
    set_tcp_nodelay(true);  // the listening socket; each accepted one is set in serve() too
  }

 private:
  // Replaces httplib's own loop over the requests of one connection (the same loop, over a
  // DeadlineStream), after the gate.
  bool process_and_close_socket(socket_t sock) override {
    const std::string address = peer_address(sock);
    bool ok = false;
    // httplib's select() cannot watch this socket, and its request parser would answer it a 500.
    const auto refusal = sock >= FD_SETSIZE ? std::optional<std::string>("the server has too many sockets open")
                                            : gate_.admit(address);
    if (refusal) {
      ++counts_.refused;
      refuse(sock, *refusal);
    } else {
      ++counts_.open;
      ok = serve(sock);
      --counts_.open;
      gate_.release(address);
    }
    ::shutdown(sock, SHUT_RDWR);
    ::close(sock);
    return ok;
  }

  bool serve(int sock) {
    const int one = 1;
    ::setsockopt(sock, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    DeadlineStream strm(sock, limits_, svr_sock_, counts_);
    bool ok = false;
    for (size_t left = keep_alive_max_count_; left > 0 && svr_sock_ != INVALID_SOCKET && strm.next_request(); --left) {
      bool closed = false;
      ok = process_request(strm, left == 1, closed, [&](httplib::Request&) { strm.headers_received(); });
      if (!ok || closed) break;
    }
    return ok;
  }

  // The 503 goes out at once; the client's request is then read and dropped for a moment, since
  // closing a socket with unread bytes resets the connection and the client may lose the answer.
  void refuse(int sock, const std::string& why) {
    const std::string r = raw_response(Error("unavailable", why + "; retry later"),
                                       "Retry-After: " + std::to_string(limits_.retry_after_s) + "\r\n");
    ::send(sock, r.data(), r.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
    ::shutdown(sock, SHUT_WR);
    char sink[4096];
    const auto until = Clock::now() + std::chrono::seconds(1);
    for (pollfd p{sock, POLLIN, 0}; Clock::now() < until;) {
      if (::poll(&p, 1, 100) > 0 && ::recv(sock, sink, sizeof sink, MSG_DONTWAIT) <= 0) break;
    }
  }

  const ConnectionLimits limits_;
  ConnectionCounts& counts_;
  ConnectionGate gate_;
};

}  // namespace

std::unique_ptr<httplib::Server> make_limited_server(const ConnectionLimits& limits, ConnectionCounts& counts) {
  return std::make_unique<LimitedServer>(limits, counts);
}

}  // namespace btfvq::server
