// The real `btfvq-server` binary running real compression jobs, driven by the real `btfvq` CLI on
// 127.0.0.1: submit -> watch -> download (sha256 verified) -> decode; two jobs into one database;
// kill -9 in the middle of a job, restart, and the job completes with the same database bytes.
#include <doctest/doctest.h>
#include <httplib.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "pipeline/format/database.h"
#include "pipeline/decode/reconstruct.h"
#include "pipeline/util/sha256.h"
#include "support/server_process.h"
#include "support/test_paths.h"

using namespace btfvq;
using namespace btfvq::test;
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

// Submits a job with the CLI and waits until it is done; returns the job id.
std::string run_job(const fs::path& dir, const std::string& server_args, const std::string& job_args) {
  const CliRun job = run_btfvq(dir, "submit " + server_args + " " + job_args);
  REQUIRE(job.status == 0);
  REQUIRE(run_btfvq(dir, "watch " + server_args + " " + job.out).status == 0);
  return job.out;
}

}  // namespace

TEST_CASE("real jobs: submit, watch, download with sha256, two versions of one database, decode") {
  const fs::path dir = scratch_dir("e2e-jobs");
  ServerProcess server(dir / "data", free_loopback_port());
  const std::string s = "--server " + server.url();

  run_job(dir, s, "--db shop --synthetic tile:8 --name tile8");
  run_job(dir, s, "--db shop --synthetic wood:8 --name wood8");

  const json info = get_json(server.url(), "/v1/databases/shop");
  CHECK(info["versions"].size() == 2);
  REQUIRE(run_btfvq(dir, "download " + s + " shop --out " + (dir / "shop.btfdb").string()).status == 0);
  const Database db = read_database((dir / "shop.btfdb").string());
  REQUIRE(db.materials.size() == 2);
  CHECK(db.materials[0].name == "tile8");
  CHECK(db.materials[1].name == "wood8");
  const MeasuredSample tile = reconstruct_bonn(db, "tile8");
  double sum = 0;
  for (uint8_t v : tile.ldr_data()) sum += v;
  CHECK(sum / double(tile.ldr_data().size()) > 20.0);  // a real, lit material came back
  CHECK(run_btfvq(dir, "ls " + s).out.find("shop") != std::string::npos);
}

TEST_CASE("kill -9 during a job, restart: the job completes with the same database as an uninterrupted run") {
  const fs::path dir = scratch_dir("e2e-kill");
  const std::string job_args = " --db fabric --synthetic fabric:20 --name f --seed 4";
  // Uninterrupted reference run.
  std::string reference;
  {
    ServerProcess server(dir / "clean", free_loopback_port());
    run_job(dir, "--server " + server.url(), job_args);
    REQUIRE(run_btfvq(dir, "download --server " + server.url() + " fabric --out " + (dir / "clean.btfdb").string()).status == 0);
    reference = file_bytes(dir / "clean.btfdb");
  }
  const int port = free_loopback_port();
  ServerProcess server(dir / "killed", port);
  const CliRun job = run_btfvq(dir, "submit --server " + server.url() + job_args);
  REQUIRE(job.status == 0);
  // Wait until the job is encoding, then kill the server without warning.
  bool encoding = false;
  for (int i = 0; i < 3000 && !encoding; ++i) {
    const json j = get_json(server.url(), "/v1/jobs/" + job.out);
    encoding = j.value("state", "") == "running" && j.value("stage", "").rfind("phase", 0) == 0;
    if (!encoding) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  REQUIRE(encoding);
  server.kill9();
  server.start();
  REQUIRE(run_btfvq(dir, "watch --server " + server.url() + " " + job.out).status == 0);
  REQUIRE(run_btfvq(dir, "download --server " + server.url() + " fabric --out " + (dir / "killed.btfdb").string()).status == 0);
  CHECK(file_bytes(dir / "killed.btfdb") == reference);
  const json info = get_json(server.url(), "/v1/databases/fabric");
  CHECK(info["versions"].size() == 1);  // nothing half-written was published
}

TEST_CASE("20 concurrent clients poll and download while a job runs: no failed request, no corrupt download") {
  const fs::path dir = scratch_dir("e2e-load");
  ServerProcess server(dir / "data", free_loopback_port());
  const std::string s = "--server " + server.url();
  run_job(dir, s, "--db load --synthetic tile:8 --name a");
  const CliRun running = run_btfvq(dir, "submit " + s + " --db load --synthetic fabric:16 --name b");
  REQUIRE(running.status == 0);

  std::atomic<int> failures{0}, corrupt{0}, downloads{0}, polls{0};
  std::vector<std::thread> clients;
  for (int c = 0; c < 20; ++c)
    clients.emplace_back([&] {
      httplib::Client http(server.url());
      http.set_read_timeout(30, 0);
      for (int i = 0; i < 10; ++i) {  // bounded: 20 clients x 10 rounds
        auto st = http.Get(("/v1/jobs/" + running.out).c_str());
        if (!st || st->status != 200) ++failures;
        else ++polls;
        auto dl = http.Get("/v1/databases/load/content");
        if (!dl || dl->status != 200) {
          ++failures;
          continue;
        }
        ++downloads;
        if (sha256_hex(dl->body) != dl->get_header_value("X-Content-Sha256")) ++corrupt;
      }
    });
  for (auto& t : clients) t.join();
  CHECK(failures == 0);
  CHECK(corrupt == 0);
  CHECK(polls == 200);
  CHECK(downloads == 200);
  CHECK(run_btfvq(dir, "watch " + s + " " + running.out).status == 0);
}

TEST_CASE("cancel a running job: watch reports it, nothing is published") {
  const fs::path dir = scratch_dir("e2e-cancel");
  ServerProcess server(dir / "data", free_loopback_port());
  const CliRun job = run_btfvq(dir, "submit --server " + server.url() + " --db c --synthetic wool:32 --name w");
  REQUIRE(job.status == 0);
  bool running = false;
  for (int i = 0; i < 3000 && !running; ++i) {
    running = get_json(server.url(), "/v1/jobs/" + job.out).value("state", "") == "running";
    if (!running) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  REQUIRE(running);
  httplib::Client http(server.url());
  auto r = http.Delete(("/v1/jobs/" + job.out).c_str());
  REQUIRE(r);
  CHECK(r->status < 300);
  CHECK(run_btfvq(dir, "watch --server " + server.url() + " " + job.out).status == 5);
  CHECK(get_json(server.url(), "/v1/jobs/" + job.out)["state"] == "cancelled");
  auto db = http.Get("/v1/databases/c");
  REQUIRE(db);
  CHECK(db->status == 404);
}
