#include "support/test_paths.h"

#include <doctest/doctest.h>

#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <sys/wait.h>

namespace btfvq::test {

namespace fs = std::filesystem;

fs::path testdata_dir() { return fs::path(BTFVQ_TESTDATA_DIR); }
fs::path source_dir() { return fs::path(BTFVQ_SOURCE_DIR); }
fs::path bin_dir() { return fs::path(BTFVQ_BIN_DIR); }

namespace {
struct ScratchRoot {
  fs::path path;
  ScratchRoot() {
    path = fs::temp_directory_path() / ("btfvq-test-" + std::to_string(::getpid()));
    fs::create_directories(path);
  }
  ~ScratchRoot() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};
}  // namespace

fs::path scratch_dir(const std::string& name) {
  static ScratchRoot root;
  fs::path p = root.path / name;
  fs::remove_all(p);
  fs::create_directories(p);
  return p;
}

int free_loopback_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr);
  socklen_t len = sizeof addr;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  ::close(fd);
  return ntohs(addr.sin_port);
}

int connect_loopback(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  REQUIRE(fd >= 0);
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(uint16_t(port));
  to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  REQUIRE(::connect(fd, reinterpret_cast<sockaddr*>(&to), sizeof to) == 0);
  return fd;
}

int run_command(const std::string& command, std::string* output) {
  FILE* pipe = ::popen((command + " 2>&1").c_str(), "r");
  if (!pipe) return -1;
  std::array<char, 4096> buffer{};
  std::string out;
  size_t n;
  while ((n = std::fread(buffer.data(), 1, buffer.size(), pipe)) > 0) out.append(buffer.data(), n);
  const int status = ::pclose(pipe);
  if (output) *output = out;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

std::string file_bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

CliRun run_btfvq(const fs::path& dir, const std::string& args) {
  CliRun r;
  const fs::path out = dir / "cli-stdout.txt";
  r.status = run_command((bin_dir() / "btfvq").string() + " " + args + " > " + out.string(), &r.all);
  r.out = file_bytes(out);
  r.all = r.out + r.all;
  while (!r.out.empty() && (r.out.back() == '\n' || r.out.back() == ' ')) r.out.pop_back();
  if (r.status != 0) MESSAGE("btfvq " << args << " -> " << r.status << ": " << r.all);
  return r;
}

std::string btfvq_ok(const fs::path& dir, const std::string& args) {
  const CliRun r = run_btfvq(dir, args);
  INFO("btfvq " << args << ": " << r.all);
  REQUIRE(r.status == 0);
  return r.out;
}

}  // namespace btfvq::test
