// The server under slow and idle clients (issue 21): real sockets on 127.0.0.0/8 against a real
// server with the shipped connection limits (configs/server.json).
#include "server_fixture.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <fcntl.h>
#include <poll.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include "server/server_config.h"

using namespace btfvq;
using namespace btfvq::test;
using Clock = std::chrono::steady_clock;

namespace {

server::HttpOptions shipped() { return server::load_server_config({}).http; }

double seconds_since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

// The test's own sockets live at 1024 and above, so that the server's sockets in this process keep
// the numbers below 1024 that they would have in a process of their own (httplib's select()
// cannot watch the others, and the server refuses them).
constexpr int kClientFds = 1024;
const bool room_for_client_fds = [] {
  rlimit r{};
  getrlimit(RLIMIT_NOFILE, &r);
  r.rlim_cur = std::max<rlim_t>(r.rlim_cur, std::min<rlim_t>(r.rlim_max, 4096));
  setrlimit(RLIMIT_NOFILE, &r);
  getrlimit(RLIMIT_NOFILE, &r);
  return r.rlim_cur >= kClientFds + 1024;
}();

// A connection from `source` (any 127.x.y.z: each is an address of its own to the server).
int connect_from(const std::string& source, int port) {
  REQUIRE_MESSAGE(room_for_client_fds, "the open-file limit must allow 2048 sockets");
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  REQUIRE(fd >= 0);
  sockaddr_in from{};
  from.sin_family = AF_INET;
  REQUIRE(inet_pton(AF_INET, source.c_str(), &from.sin_addr) == 1);
  REQUIRE(::bind(fd, reinterpret_cast<sockaddr*>(&from), sizeof from) == 0);
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(uint16_t(port));
  to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  REQUIRE(::connect(fd, reinterpret_cast<sockaddr*>(&to), sizeof to) == 0);
  const int high = fcntl(fd, F_DUPFD_CLOEXEC, kClientFds);
  REQUIRE(high >= kClientFds);
  ::close(fd);
  return high;
}

void send_all(int fd, const std::string& bytes) {
  for (size_t sent = 0; sent < bytes.size();) {
    const ssize_t n = ::send(fd, bytes.data() + sent, bytes.size() - sent, MSG_NOSIGNAL);
    REQUIRE(n > 0);
    sent += size_t(n);
  }
}

// Everything the server sends until it closes, or until `seconds` pass.
std::string read_until_close(int fd, double seconds) {
  std::string out;
  const auto until = Clock::now() + std::chrono::duration<double>(seconds);
  char buf[4096];
  while (Clock::now() < until) {
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, 50) <= 0) continue;
    const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
    if (n <= 0) break;
    out.append(buf, size_t(n));
  }
  return out;
}

// Whether the server has answered or closed `fd` (without waiting).
bool answered(int fd) {
  pollfd p{fd, POLLIN, 0};
  return ::poll(&p, 1, 0) > 0;
}

size_t thread_count() {
  size_t n = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator("/proc/self/task")) ++n;
  return n;
}

// A request cut off in the middle of its headers.
const std::string kHalfHeader = "GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ";

struct Connections {
  std::vector<int> fds;
  ~Connections() {
    for (int fd : fds) ::close(fd);
  }
};

// Sends `chunk` about once a second until the server answers (then reads the answer to the close)
// or `seconds` pass; returns the answer, empty if none came.
std::string trickle_until_answer(int fd, const std::string& chunk, double seconds) {
  const auto start = Clock::now();
  while (seconds_since(start) < seconds) {
    if (::send(fd, chunk.data(), chunk.size(), MSG_NOSIGNAL) != ssize_t(chunk.size())) break;
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, 1000) > 0) return read_until_close(fd, 2);
  }
  return {};
}

}  // namespace

TEST_CASE("the shipped connection limits are the defaults the server is built with") {
  const auto k = shipped().connections;
  const server::ConnectionLimits built;
  CHECK(k.max_connections == built.max_connections);
  CHECK(k.max_connections_per_client == built.max_connections_per_client);
  CHECK(k.header_timeout_s == built.header_timeout_s);
  CHECK(k.body_min_bytes_per_s == built.body_min_bytes_per_s);
  CHECK(k.retry_after_s == built.retry_after_s);
  CHECK(k.idle_timeout_s == built.idle_timeout_s);
  CHECK(k.max_connections >= 300);  // "a few hundred idle connections"
}

TEST_CASE("a config that still sets the old fixed pool (http_threads) is refused with a message naming its replacement") {
  const std::filesystem::path file = std::filesystem::temp_directory_path() / "btfvq_old_http_threads.json";
  std::ofstream(file) << R"({"http_threads": 16})";
  server::ServerFlags flags;
  flags.config_file = file.string();
  try {
    server::load_server_config(flags);
    FAIL("http_threads was accepted");
  } catch (const ConfigError& e) {
    CHECK(std::string(e.what()).find("http_max_connections") != std::string::npos);
  }
  std::filesystem::remove(file);
}

TEST_CASE("200 connections stalled in their headers leave /healthz and downloads answering within 1 s") {
  const auto options = shipped();
  TestServer t("slow-200", {}, options);
  auto c = t.client();
  auto job = c.Post("/v1/jobs", synthetic_job("slowdb", "wool", 8, 1).dump(), "application/json");
  REQUIRE(job);
  REQUIRE(job->status == 202);
  REQUIRE(wait_final(*t.service, json::parse(job->body)["id"])["state"] == "succeeded");
  const size_t threads_before = thread_count();

  // 10 addresses with 20 connections each: within the per-client cap, so all 200 are held open.
  Connections stalled;
  for (int i = 0; i < 200; ++i) {
    stalled.fds.push_back(connect_from("127.0.1." + std::to_string(10 + i / 20), t.port));
    send_all(stalled.fds.back(), kHalfHeader);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  const size_t threads_held = thread_count();
  MESSAGE("threads: " << threads_before << " before, " << threads_held << " with 200 stalled connections");
  CHECK(threads_held >= threads_before + 150);  // the stalled connections are really being served
  CHECK(threads_held <= threads_before + 200 + 8 + 2);

  for (int round = 0; round < 3; ++round) {
    auto other = t.client();
    auto start = Clock::now();
    auto h = other.Get("/healthz");
    REQUIRE(h);
    CHECK(h->status == 200);
    CHECK(seconds_since(start) < 1.0);
    start = Clock::now();
    auto d = other.Get("/v1/databases/slowdb/content");
    REQUIRE(d);
    CHECK(d->status == 200);
    CHECK(d->body.rfind("FAKEBTFDB\n", 0) == 0);
    CHECK(seconds_since(start) < 1.0);
  }
  size_t still_open = 0;
  for (int fd : stalled.fds) still_open += !answered(fd);
  CHECK(still_open == 200);
  CHECK(thread_count() <= threads_before + 200 + 8 + 2);
}

TEST_CASE("beyond the per-client and the total cap a connection is answered 503 with Retry-After") {
  const auto options = shipped();
  const auto& k = options.connections;
  TestServer t("slow-caps", {}, options);
  const std::string request = "GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n";
  auto check_refused = [&](const std::string& source, const std::string& why) {
    const int fd = connect_from(source, t.port);
    send_all(fd, request);
    const std::string r = read_until_close(fd, 5);
    ::close(fd);
    CAPTURE(r);
    CHECK(r.rfind("HTTP/1.1 503 ", 0) == 0);
    CHECK(r.find("\r\nRetry-After: " + std::to_string(k.retry_after_s) + "\r\n") != std::string::npos);
    const auto body = json::parse(r.substr(r.find("\r\n\r\n") + 4));
    CHECK(body["error"]["code"] == "unavailable");
    CHECK(body["error"]["message"].get<std::string>().find(why) != std::string::npos);
  };
  auto check_served = [&](const std::string& source) {
    const int fd = connect_from(source, t.port);
    send_all(fd, request);
    const std::string r = read_until_close(fd, 5);
    ::close(fd);
    CHECK(r.rfind("HTTP/1.1 200 ", 0) == 0);
  };

  Connections held;
  for (int i = 0; i < k.max_connections_per_client; ++i) {
    held.fds.push_back(connect_from("127.0.2.1", t.port));
    send_all(held.fds.back(), kHalfHeader);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  check_refused("127.0.2.1", "the limit per client");
  check_served("127.0.2.2");

  // Fill the server up to its total from further addresses, each within its own cap.
  for (int i = int(held.fds.size()); i < k.max_connections; ++i) {
    const int n = i / k.max_connections_per_client;
    held.fds.push_back(connect_from("127.0.3." + std::to_string(1 + n), t.port));
    send_all(held.fds.back(), kHalfHeader);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  check_refused("127.0.4.1", "its limit");
  size_t still_open = 0;
  for (int fd : held.fds) still_open += !answered(fd);
  CHECK(still_open == size_t(k.max_connections));
  // Counted for /metrics; the one slot that frees up below lets the scrape itself in.
  ::close(held.fds.back());
  held.fds.pop_back();
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  const auto scrape = t.client().Get("/metrics");
  REQUIRE(scrape);
  CHECK(metric(scrape->body, "btfvq_http_connections_refused_total") == 2);
  CHECK(metric(scrape->body, "btfvq_http_connections") == k.max_connections);  // the held ones and the scrape

  // Once the scrape is gone, its slot is open to the next client again.
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  check_served("127.0.4.1");
}

TEST_CASE("a client that trickles a header byte per second is cut off at the header deadline with 408") {
  const auto options = shipped();
  const double deadline = options.connections.header_timeout_s;
  TestServer t("slow-trickle", {}, options);
  const int fd = connect_from("127.0.5.1", t.port);
  const auto start = Clock::now();
  send_all(fd, "GET /healthz HTTP/1.1\r\n");
  const std::string r = trickle_until_answer(fd, "a", deadline + 5);
  const double cut = seconds_since(start);
  ::close(fd);
  MESSAGE("cut off after " << cut << " s");
  CHECK(cut >= deadline - 0.5);
  CHECK(cut < deadline + 2);
  CAPTURE(r);
  CHECK(r.rfind("HTTP/1.1 408 ", 0) == 0);
  CHECK(json::parse(r.substr(r.find("\r\n\r\n") + 4))["error"]["code"] == "request_timeout");
  CHECK(metric(t.client().Get("/metrics")->body, "btfvq_http_requests_timed_out_total") == 1);
}

TEST_CASE("an upload body slower than the minimum rate is cut off with 408, and nothing of it is kept") {
  const auto options = shipped();
  const auto& k = options.connections;
  TestServer t("slow-body", {}, options);
  const int fd = connect_from("127.0.5.2", t.port);
  send_all(fd, "PUT /v1/uploads/trickled HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/octet-stream\r\n"
               "Content-Length: 1048576\r\n\r\n");
  const auto start = Clock::now();
  // 1 KiB a second: the body's deadline, grace + bytes / rate, is passed after grace * 16/15 s.
  const double expected = k.header_timeout_s / (1.0 - 1024.0 / k.body_min_bytes_per_s);
  const std::string r = trickle_until_answer(fd, std::string(1024, 'b'), expected + 5);
  const double cut = seconds_since(start);
  ::close(fd);
  MESSAGE("body cut off after " << cut << " s (expected " << expected << " s)");
  CHECK(cut >= expected - 1.5);
  CHECK(cut < expected + 2);
  CAPTURE(r);
  CHECK(r.rfind("HTTP/1.1 408 ", 0) == 0);
  CHECK(json::parse(r.substr(r.find("\r\n\r\n") + 4))["error"]["code"] == "request_timeout");
  CHECK(t.client().Get("/v1/uploads/trickled")->status == 404);
}

TEST_CASE("the server stops at once while stalled connections are open") {
  TestServer t("slow-stop", {}, shipped());
  Connections stalled;
  for (int i = 0; i < 20; ++i) {
    stalled.fds.push_back(connect_from("127.0.6.1", t.port));
    send_all(stalled.fds.back(), kHalfHeader);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  const auto start = Clock::now();
  t.http->stop();
  MESSAGE("stopped in " << seconds_since(start) << " s");
  CHECK(seconds_since(start) < 1.0);
  size_t closed = 0;
  for (int fd : stalled.fds) closed += read_until_close(fd, 1).empty() && answered(fd);
  CHECK(closed == stalled.fds.size());  // closed without an answer: a 408 is for clients that were late
}
