#pragma once
// The real btfvq-server binary as a child process, for integration tests.
#include <doctest/doctest.h>
#include <httplib.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>

#include "support/test_paths.h"

namespace btfvq::test {
namespace fs = std::filesystem;

// One btfvq-server process over a data directory; stop() is a clean SIGTERM, kill() a kill -9.
class ServerProcess {
 public:
  ServerProcess(const fs::path& data, int port) : data_(data), port_(port) { start(); }
  ~ServerProcess() { stop(); }

  void start() {
    const std::string server = (bin_dir() / "btfvq-server").string();
    const std::string listen = "127.0.0.1:" + std::to_string(port_), data = data_.string();
    const std::string log = (data_.parent_path() / (data_.filename().string() + ".log")).string();
    pid_ = ::fork();
    REQUIRE(pid_ >= 0);
    if (pid_ == 0) {
      if (FILE* f = std::freopen(log.c_str(), "a", stderr)) (void)f;
      ::execl(server.c_str(), server.c_str(), "--listen", listen.c_str(), "--data", data.c_str(), "--workers", "1",
              static_cast<char*>(nullptr));
      ::_exit(127);
    }
    httplib::Client c(url());
    for (int i = 0; i < 1000; ++i) {
      auto r = c.Get("/healthz");
      if (r && r->status == 200) return;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    FAIL("btfvq-server did not answer /healthz");
  }
  void stop() { signal_and_wait(SIGTERM); }
  void kill9() { signal_and_wait(SIGKILL); }
  std::string url() const { return "http://127.0.0.1:" + std::to_string(port_); }

 private:
  void signal_and_wait(int sig) {
    if (pid_ <= 0) return;
    ::kill(pid_, sig);
    int status = 0;
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
  }
  fs::path data_;
  int port_;
  pid_t pid_ = -1;
};

// GET `path` from the server at `url`, REQUIRing 200; the body as JSON.
inline nlohmann::json get_json(const std::string& url, const std::string& path) {
  httplib::Client c(url);
  auto r = c.Get(path.c_str());
  REQUIRE(r);
  REQUIRE(r->status == 200);
  return nlohmann::json::parse(r->body);
}

}  // namespace btfvq::test
