#pragma once
// Shared by the tests/test_server_*.cpp files: a small executor that writes a real database-like
// file (so the queue, publication and downloads are exercised for real), and a server started
// in-process on 127.0.0.1 with a random free port over a scratch data directory.
#include <doctest/doctest.h>
#include <archive.h>
#include <archive_entry.h>
#include <httplib.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <functional>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <btfvq/error.h>
#include "pipeline/io/sample_io.h"
#include "pipeline/util/atomic_file.h"
#include "pipeline/util/sha256.h"
#include "server/http_server.h"
#include "server/service.h"
#include "support/test_paths.h"

namespace btfvq::test {

// Quiet logs: the tests assert on state, not on log lines.
inline const bool quiet_logs = [] {
  spdlog::set_level(spdlog::level::warn);
  return true;
}();

namespace fs = std::filesystem;
using nlohmann::json;

inline std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// The value of one Prometheus sample line "name value" in a /metrics body.
inline double metric(const std::string& text, const std::string& name) {
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line))
    if (line.rfind(name + " ", 0) == 0) return std::stod(line.substr(name.size() + 1));
  FAIL("no metric " << name);
  return -1;
}

inline void write_file(const fs::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out << bytes;
}

// A zip (deflated) with the given (name, content) entries, written with libarchive as a hostile
// client would: names are not checked here.
inline void write_archive(const fs::path& path, const std::vector<std::pair<std::string, std::string>>& entries) {
  archive* a = archive_write_new();
  archive_write_set_format_zip(a);
  archive_write_set_options(a, "zip:compression=deflate");
  REQUIRE(archive_write_open_filename(a, path.c_str()) == ARCHIVE_OK);
  for (const auto& [name, content] : entries) {
    archive_entry* e = archive_entry_new();
    archive_entry_set_pathname(e, name.c_str());
    archive_entry_set_size(e, la_int64_t(content.size()));
    archive_entry_set_filetype(e, AE_IFREG);
    archive_entry_set_perm(e, 0644);
    archive_write_header(a, e);
    archive_write_data(a, content.data(), content.size());
    archive_entry_free(e);
  }
  archive_write_close(a);
  archive_write_free(a);
}

// The bytes of a real (tiny: 2 x 2 texels, 81 x 81 directions) UBO2003 zip: the server checks a
// sample's names and first image when a job is submitted.
inline const std::string& tiny_sample_zip() {
  static const std::string bytes = [] {
    MeasuredSample s = make_bonn_sample(2, 2, Dynamic::LDR);
    for (size_t i = 0; i < s.ldr_data().size(); ++i) s.ldr_data()[i] = uint8_t(40 + i % 150);
    const fs::path p = scratch_dir("tiny-sample") / "tiny.zip";
    write_sample(s, p.string());
    return read_file(p);
  }();
  return bytes;
}

// Behaviour by synthetic preset: "wool" compresses (progress through phases 1-3, then writes),
// "tile" fails with an InputError, "foil" runs until cancelled, "leather" waits for release().
struct FakeCompressor {
  std::mutex mutex;
  std::condition_variable cv;
  std::vector<std::string> log;  // "start <db> <material>", "end <db> <material>"
  bool released = false;
  int running = 0, max_running = 0;
  std::chrono::milliseconds step{5};

  void release() {
    std::lock_guard lock(mutex);
    released = true;
    cv.notify_all();
  }
  std::vector<std::string> events() {
    std::lock_guard lock(mutex);
    return log;
  }

  server::Executor executor() {
    return [this](const server::JobSpec& spec, const std::string& previous, const std::string& out,
                  server::JobContext& ctx) {
      const std::string first = spec.materials.at(0).name;
      {
        std::lock_guard lock(mutex);
        log.push_back("start " + spec.database + " " + first);
        max_running = std::max(max_running, ++running);
      }
      struct Done {
        FakeCompressor* f;
        std::string what;
        ~Done() {
          std::lock_guard lock(f->mutex);
          --f->running;
          f->log.push_back(what);
        }
      } done{this, "end " + spec.database + " " + first};
      std::string bytes = previous.empty() ? std::string("FAKEBTFDB\n") : read_file(previous);
      for (size_t i = 0; i < spec.materials.size(); ++i) {
        const auto& m = spec.materials[i];
        if (m.preset == "tile") throw InputError("material '" + m.name + "': the tile preset is broken in this test");
        if (m.preset == "foil") {
          for (int k = 0; k < 4000 && !ctx.cancelled(); ++k) {
            ctx.progress({"phase1", 1, 0.1, uint64_t(k), 4000, {}, m.name});
            std::this_thread::sleep_for(std::chrono::milliseconds(5));
          }
          throw CancelledError();
        }
        if (m.preset == "leather") {
          std::unique_lock lock(mutex);
          const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(20);
          while (!released && !ctx.cancelled() && std::chrono::steady_clock::now() < until)
            cv.wait_for(lock, std::chrono::milliseconds(5));
        }
        for (int phase = 1; phase <= 3; ++phase) {
          for (int k = 1; k <= 3; ++k) {
            if (ctx.cancelled()) throw CancelledError();
            server::JobProgress p;
            p.stage = "phase" + std::to_string(phase);
            p.phase = phase;
            p.fraction = (double(i) + (phase - 1 + k / 3.0) / 3.0) / double(spec.materials.size());
            p.texels_done = uint64_t(k * 100);
            p.texels_total = 300;
            p.codebook_sizes.rows = {size_t(10 * phase), 2, 3, 4, 5, 6, 7, size_t(8 * phase)};
            p.material = m.name;
            ctx.progress(p);
            std::this_thread::sleep_for(step);
          }
        }
        std::string line = "material " + m.name + " " + m.kind + " seed " + std::to_string(m.seed);
        if (!m.file.empty()) line += " file-sha256 " + sha256_file(m.file);
        bytes += line + "\n";
        std::mt19937 rng(uint32_t(m.seed + 7));
        for (int k = 0; k < m.size * 1024; ++k) bytes += char('a' + rng() % 26);
        bytes += "\n";
        ctx.added.push_back({m.name, uint64_t(m.size) * m.size * 81 * 81 * 3, m.size, m.size, json{{"fake", true}}});
      }
      write_file_atomically(out, bytes);
    };
  }
};

inline json synthetic_job(const std::string& db, const std::string& preset, int size = 8, int seed = 1,
                          const std::string& name = "") {
  json m = {{"source", {{"synthetic", {{"preset", preset}, {"size", size}, {"seed", seed}}}}}};
  if (!name.empty()) m["name"] = name;
  return {{"database", db}, {"materials", json::array({m})}};
}

// A job in a final state stays there: waiting on would only turn its error into a timeout.
inline bool final_state(const json& job) { return server::is_final(job["state"].get<server::JobState>()); }

// Polls until the job is in `state` (empty: any final state); another final state or the deadline
// fails with the job's JSON and what `explain` adds (the Slurm test: the cluster's own view).
inline json wait_state(server::Service& s, const std::string& id, const std::string& state, double seconds = 20,
                       const std::function<std::string()>& explain = {}) {
  const auto start = std::chrono::steady_clock::now();
  const auto until = start + std::chrono::duration<double>(seconds);
  for (;;) {
    json j = s.job(id);
    const bool final = final_state(j);
    if (state.empty() ? final : j["state"] == state) return j;
    const auto now = std::chrono::steady_clock::now();
    if (final || now > until)
      FAIL("job " << id << " never reached " << (state.empty() ? "a final state" : state) << ": " << j.dump()
                  << (explain ? "\n" + explain() : ""));
    // Quick jobs are seen at once; a long one (a Slurm run) need not be asked 500 times a second.
    std::this_thread::sleep_for(std::chrono::milliseconds(now - start < std::chrono::seconds(1) ? 2 : 20));
  }
}

inline json wait_final(server::Service& s, const std::string& id, double seconds = 20) {
  return wait_state(s, id, "", seconds);
}

// Every file under `dir` (relative path -> size), to assert that a rejection changed nothing.
inline std::map<std::string, uintmax_t> tree(const fs::path& dir) {
  std::map<std::string, uintmax_t> out;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.is_regular_file() && e.path().filename().string().find("sqlite") == std::string::npos)
      out[fs::relative(e.path(), dir).string()] = e.file_size();
  return out;
}

// A Service plus HttpServer on 127.0.0.1:<random port>.
struct TestServer {
  fs::path root;
  FakeCompressor fake;
  std::unique_ptr<server::Service> service;
  std::unique_ptr<server::HttpServer> http;
  int port = 0;

  explicit TestServer(const std::string& name, server::ServiceConfig config = {}, server::HttpOptions options = {}) {
    root = scratch_dir(name);
    if (config.data_dir.empty()) config.data_dir = root / "data";
    service = std::make_unique<server::Service>(config, fake.executor());
    service->start();
    http = std::make_unique<server::HttpServer>(*service, options);
    port = http->bind("127.0.0.1", 0);
    http->run_in_background();
  }
  ~TestServer() {
    fake.release();
    http->stop();
    service->stop();
  }
  std::string url() const { return "http://127.0.0.1:" + std::to_string(port); }
  httplib::Client client(const std::string& token = "") const {
    httplib::Client c(url());
    c.set_read_timeout(30);
    if (!token.empty()) c.set_bearer_token_auth(token);
    return c;
  }
  fs::path data() const { return service->config().data_dir; }
};

}  // namespace btfvq::test
