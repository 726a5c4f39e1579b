#pragma once
// Where tests find the outside test data, the built binaries, and a scratch directory.
#include <filesystem>
#include <string>

namespace btfvq::test {

std::filesystem::path testdata_dir();   // tests/data
std::filesystem::path source_dir();     // the repository root
std::filesystem::path bin_dir();        // build/bin (btfvq, btfvq-server)
// A fresh, empty directory unique to this test process and `name`; removed when the process ends.
std::filesystem::path scratch_dir(const std::string& name);

// A TCP port on 127.0.0.1 that was free a moment ago (for servers started by tests).
int free_loopback_port();
// A TCP connection to 127.0.0.1:port (REQUIREs success); the caller closes the descriptor.
int connect_loopback(int port);

// Runs a shell command, returns its exit status; stdout+stderr go to `output` when given.
int run_command(const std::string& command, std::string* output = nullptr);

// A whole file's bytes ("" when it cannot be read).
std::string file_bytes(const std::filesystem::path& p);

// `btfvq ARGS` (the built CLI) with its stdout kept apart, in a file under `dir`: the exit status,
// stdout without its trailing newline, and stdout+stderr. A failure is reported as a test MESSAGE.
struct CliRun {
  int status = -1;
  std::string out, all;
};
CliRun run_btfvq(const std::filesystem::path& dir, const std::string& args);
// The same, REQUIRing success; returns stdout.
std::string btfvq_ok(const std::filesystem::path& dir, const std::string& args);

}  // namespace btfvq::test
