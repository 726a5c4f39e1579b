// Regressions of the bugs that the fuzz of bench/bench_soak.py (issue 21 part 4) found in the
// server, each as the smallest request that showed it, over real HTTP on 127.0.0.1.
#include "server_fixture.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

using namespace btfvq;
using namespace btfvq::test;

namespace {

// Sends raw bytes, reads the answer until the server closes; returns its status (0: none).
int raw_status(int port, const std::string& bytes, std::string* answer = nullptr) {
  const int fd = connect_loopback(port);
  timeval tv{10, 0};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  size_t sent = 0;
  while (sent < bytes.size()) {
    const ssize_t n = ::send(fd, bytes.data() + sent, bytes.size() - sent, MSG_NOSIGNAL);
    if (n <= 0) break;
    sent += size_t(n);
  }
  ::shutdown(fd, SHUT_WR);
  std::string got;
  char buf[4096];
  for (ssize_t n; (n = ::recv(fd, buf, sizeof buf, 0)) > 0;) got.append(buf, size_t(n));
  ::close(fd);
  if (answer) *answer = got;
  if (got.rfind("HTTP/1.1 ", 0) != 0 || got.size() < 12) return 0;
  return std::stoi(got.substr(9, 3));
}

bool healthy(TestServer& t) {
  auto c = t.client();
  auto r = c.Get("/healthz");
  return r && r->status == 200;
}

}  // namespace

TEST_CASE("a path segment that is not UTF-8 gets its 404, not an abort while the error is written") {
  // httplib decodes %FF into the byte 0xFF; the error message quotes the id, and nlohmann::json
  // threw type_error 316 from dump() inside the exception handler: std::terminate.
  TestServer t("fuzz-utf8");
  std::string answer;
  CHECK(raw_status(t.port, "GET /v1/jobs/%FF%FEx HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n", &answer) == 404);
  CHECK(answer.find("\"not_found\"") != std::string::npos);
  CHECK(raw_status(t.port, "GET /v1/databases/a%C0%AF/content HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n") == 404);
  CHECK(raw_status(t.port, "GET /v1/uploads/%E2%28%A1 HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n") / 100 == 4);
  CHECK(raw_status(t.port, "DELETE /v1/jobs/\xff\xfe HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n") / 100 == 4);
  CHECK(healthy(t));
}

TEST_CASE("GET of an upload id that cannot name a file is a 404, not a 500 from the file system") {
  // Uploads::info() looked the id up as a file name before checking it: "%00" read the folder
  // partial-uploads/ itself ("Is a directory"), 300 characters were "File name too long".
  TestServer t("fuzz-upload-id");
  for (const std::string& id : std::vector<std::string>{"%00", "%00.json", std::string(300, 'a'), "..", ".x", "a%2Fb"}) {
    std::string answer;
    CHECK_MESSAGE(raw_status(t.port, "GET /v1/uploads/" + id + " HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n",
                             &answer) == 404,
                  id << ": " << answer);
    CHECK(raw_status(t.port, "HEAD /v1/uploads/" + id + " HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n") == 404);
  }
  CHECK(healthy(t));
}

TEST_CASE("kept-alive requests are answered without the 40 ms of Nagle's algorithm against a delayed ACK") {
  // The soak of bench/bench_soak.py measured p95 of 42 ms for /healthz, p50 1 ms: httplib sends a
  // response's headers and body in two writes, and without TCP_NODELAY the body waited for the ACK
  // of the headers, which the client delays by up to 40 ms. 200 requests on kept-alive connections
  // (httplib closes one after 5 requests): at most a few may take that long (a busy machine can
  // delay any of them).
  TestServer t("soak-nodelay");
  auto connect = [&] {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    REQUIRE(fd >= 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(uint16_t(t.port));
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    REQUIRE(::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0);
    timeval tv{10, 0};
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    return fd;
  };
  int fd = connect(), slow = 0, answered = 0;
  std::string buffered;
  const std::string request = "GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n";
  for (int i = 0; i < 200; ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    REQUIRE(::send(fd, request.data(), request.size(), MSG_NOSIGNAL) == ssize_t(request.size()));
    bool closed = false;
    for (;;) {  // one whole answer: the headers, then Content-Length bytes
      const auto end = buffered.find("\r\n\r\n");
      if (end != std::string::npos) {
        const auto cl = buffered.find("Content-Length: ");
        REQUIRE(cl != std::string::npos);
        const size_t length = std::stoul(buffered.substr(cl + 16));
        if (buffered.size() >= end + 4 + length) {
          closed = buffered.find("Connection: close") < end;
          buffered.erase(0, end + 4 + length);
          break;
        }
      }
      char buf[4096];
      const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
      REQUIRE(n > 0);
      buffered.append(buf, size_t(n));
    }
    ++answered;
    if (std::chrono::steady_clock::now() - t0 > std::chrono::milliseconds(35)) ++slow;
    if (closed) {
      ::close(fd);
      fd = connect();
      buffered.clear();
    }
  }
  ::close(fd);
  MESSAGE(answered << " answers, " << slow << " slower than 35 ms");
  CHECK(answered == 200);
  CHECK(slow <= 4);
}
