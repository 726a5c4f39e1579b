// The real `btfvq-server` killed with SIGKILL in phase 3 of a 128 x 128 job: restarted, the job
// continues from its last checkpointed tile (its events say which), publishes the database of an
// uninterrupted run byte for byte, and its checkpoints are gone afterwards.
#include <doctest/doctest.h>
#include <httplib.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "pipeline/util/sha256.h"
#include "support/server_process.h"
#include "support/test_paths.h"

using namespace btfvq;
using namespace btfvq::test;
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

const json kJob = {{"database", "resume"},
                   {"materials", json::array({{{"name", "m"}, {"source", {{"synthetic", {{"preset", "wood"}, {"size", 128}, {"seed", 7}}}}}}})}};

std::string submit(const std::string& url) {
  httplib::Client c(url);
  auto r = c.Post("/v1/jobs", kJob.dump(), "application/json");
  REQUIRE(r);
  INFO(r->body);
  REQUIRE(r->status == 202);
  return json::parse(r->body)["id"];
}

json job(const std::string& url, const std::string& id) {
  httplib::Client c(url);
  auto r = c.Get(("/v1/jobs/" + id).c_str());
  REQUIRE(r);
  REQUIRE(r->status == 200);
  return json::parse(r->body);
}

// Every event of the job's stream until its end event, as JSON data.
std::vector<json> events_until_end(const std::string& url, const std::string& id) {
  httplib::Client c(url);
  c.set_read_timeout(900, 0);
  std::string text;
  std::vector<json> events;
  auto r = c.Get(("/v1/jobs/" + id + "/events").c_str(), [&](const char* data, size_t n) {
    text.append(data, n);
    for (size_t end; (end = text.find("\n\n")) != std::string::npos; text.erase(0, end + 2)) {
      const std::string block = text.substr(0, end);
      const size_t d = block.find("data: ");
      if (d != std::string::npos) events.push_back(json::parse(block.substr(d + 6)));
      if (block.rfind("event: end", 0) == 0) return false;
    }
    return true;
  });
  return events;
}

std::string content_sha(const std::string& url) {
  httplib::Client c(url);
  c.set_read_timeout(60, 0);
  auto r = c.Get("/v1/databases/resume/content");
  REQUIRE(r);
  REQUIRE(r->status == 200);
  CHECK(r->get_header_value("X-Content-Sha256") == sha256_hex(r->body));
  return sha256_hex(r->body);
}

}  // namespace

TEST_CASE("SIGKILL in phase 3, restart: the job resumes from its last tile and publishes the uninterrupted bytes") {
  const fs::path dir = scratch_dir("server-resume");
  std::string reference;
  {
    ServerProcess clean(dir / "clean", free_loopback_port());
    const std::string id = submit(clean.url());
    const std::vector<json> events = events_until_end(clean.url(), id);
    REQUIRE(!events.empty());
    REQUIRE(events.back()["state"] == "succeeded");
    reference = content_sha(clean.url());
  }

  const fs::path data = dir / "killed";
  ServerProcess server(data, free_loopback_port());
  const std::string id = submit(server.url());
  // Wait for the third phase-3 tile (256 texels each), then kill without warning.
  size_t done_at_kill = 0;
  for (int i = 0; i < 60000 && done_at_kill == 0; ++i) {
    const json j = job(server.url(), id);
    REQUIRE(j["state"] != "failed");
    if (j["stage"] == "phase3" && j["texels_done"].get<size_t>() >= 3 * 256) done_at_kill = j["texels_done"];
    else std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  REQUIRE(done_at_kill > 0);
  server.kill9();
  REQUIRE(fs::is_regular_file(data / "work" / id / "state.ckpt"));

  server.start();
  const std::vector<json> events = events_until_end(server.url(), id);
  REQUIRE(!events.empty());
  CHECK(events.back()["state"] == "succeeded");
  int64_t resumed = -1;
  for (const json& e : events)
    if (e.contains("resumed_from_tile") && e["resumed_from_tile"].is_number()) resumed = e["resumed_from_tile"];
  MESSAGE("killed at " << done_at_kill << " phase-3 texels; resumed after tile " << resumed);
  CHECK(resumed >= 3);
  CHECK(size_t(resumed) * 256 <= done_at_kill + 256);  // the tile the kill interrupted, at most, is redone
  CHECK(content_sha(server.url()) == reference);
  CHECK_FALSE(fs::exists(data / "work" / id));  // checkpoints removed once published
}
