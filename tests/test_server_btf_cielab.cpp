// The real `btfvq-server` asked for BTF-CIELab in a job (the job field "btf_cielab", docs/api.md):
// the job's result carries each material's value, and it is what `btfvq eval --metric btf-cielab`
// computes for the database the job published and the same sample; a job that does not ask has no
// such key; a bad value is a 400 naming the field. A 16 x 16 synthetic sample keeps it short.
#include <doctest/doctest.h>
#include <httplib.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string>

#include "support/server_process.h"
#include "support/test_paths.h"

using namespace btfvq::test;
namespace fs = std::filesystem;
using nlohmann::json;

namespace {
// Follows the job's event stream to its end (the stream closes then); returns every event's job.
std::vector<json> follow(const std::string& url, const std::string& id) {
  httplib::Client c(url);
  c.set_read_timeout(120, 0);
  auto r = c.Get(("/v1/jobs/" + id + "/events").c_str());
  REQUIRE(r);
  REQUIRE(r->status == 200);
  std::vector<json> events;
  std::istringstream in(r->body);
  for (std::string line; std::getline(in, line);)
    if (line.rfind("data: ", 0) == 0) events.push_back(json::parse(line.substr(6)));
  REQUIRE(!events.empty());
  return events;
}
bool close(double a, double b) { return std::abs(a - b) <= 1e-9 * std::max(std::abs(a), std::abs(b)); }

}  // namespace

TEST_CASE("a job with btf_cielab: its result carries what btfvq eval computes for the published database") {
  const fs::path dir = scratch_dir("server-btf-cielab");
  ServerProcess server(dir / "data", free_loopback_port());
  const std::string s = "--server " + server.url();
  const std::string sample = (dir / "leather16.zip").string();
  btfvq_ok(dir, "synth --preset leather --size 16 --seed 2 --out " + sample);

  // Not the default condition, so that the value is seen to follow the request. The job id is the
  // last line (the upload's progress comes first).
  std::string id = btfvq_ok(dir, "submit " + s + " --db shop --upload " + sample + " --name m --btf-cielab 30,200");
  id = id.substr(id.find_last_of('\n') + 1);
  const std::vector<json> events = follow(server.url(), id);
  std::set<std::string> stages;
  for (const json& e : events) stages.insert(e.value("stage", ""));
  CHECK(stages.count("btf_cielab") == 1);  // the progress says when it is computing
  REQUIRE(events.back()["state"] == "succeeded");

  const json job = get_json(server.url(), "/v1/jobs/" + id);
  CHECK(job["request"]["btf_cielab"] == "30,200");
  REQUIRE(job["results"].size() == 1);
  CHECK(job["results"][0]["name"] == "m");
  const json& got = job["results"][0]["report"]["btf_cielab"];
  for (const char* key : {"mean", "std", "rms"}) {
    CAPTURE(key);
    REQUIRE(got[key].is_number());
    CHECK(std::isfinite(got[key].get<double>()));
    CHECK(got[key].get<double>() > 0);
  }
  CHECK(got["resolution"] == 30.0);
  CHECK(got["speed"] == 200.0);
  CHECK(got["seconds"].get<double>() > 0);
  // The catalogue keeps the same report with the version.
  CHECK(get_json(server.url(), "/v1/databases/shop")["newest"]["materials"][0]["report"]["btf_cielab"] == got);

  const fs::path db = dir / "shop.btfdb", report = dir / "eval.json";
  btfvq_ok(dir, "download " + s + " shop --out " + db.string());
  btfvq_ok(dir, "eval " + db.string() + " --reference " + sample + " --metric btf-cielab:30,200 --json " + report.string());
  const json eval = json::parse(file_bytes(report))["btf_cielab"];
  CHECK(close(got["mean"].get<double>(), eval["mean"].get<double>()));
  CHECK(close(got["std"].get<double>(), eval["stddev"].get<double>()));
  CHECK(close(got["rms"].get<double>(), eval["rms"].get<double>()));
}

TEST_CASE("a job with a target: its events name each compression of the search, its result the target's report") {
  const fs::path dir = scratch_dir("server-target");
  ServerProcess server(dir / "data", free_loopback_port());
  // A target the default quality passes: the search goes down for fewer bytes.
  const std::string id =
      btfvq_ok(dir, "submit --server " + server.url() + " --db t --synthetic leather:16 --name m --target-mssim 0.3");
  const std::vector<json> events = follow(server.url(), id);
  REQUIRE(events.back()["state"] == "succeeded");
  std::vector<std::string> attempts;  // as the events say them, in order
  for (const json& e : events)
    if (e.contains("attempt") && e["attempt"].is_string() && (attempts.empty() || attempts.back() != e["attempt"]))
      attempts.push_back(e["attempt"]);
  const json job = get_json(server.url(), "/v1/jobs/" + id);
  REQUIRE(job["results"].size() == 1);
  const json& target = job["results"][0]["report"]["target"];
  CHECK(target["mssim"] == 0.3);
  CHECK(target["reached"] == true);
  REQUIRE(attempts.size() == target["attempts"].size());
  CHECK(attempts[0] == "attempt 1: quality 50");
  for (size_t k = 1; k < attempts.size(); ++k) {
    const json& before = target["attempts"][k - 1];
    CHECK(attempts[k].rfind("attempt " + std::to_string(k + 1) + ": quality ", 0) == 0);
    CHECK(attempts[k].find("attempt " + std::to_string(k) + " gave MSSIM ") != std::string::npos);
    CHECK(attempts[k].find(" at " + std::to_string(before["bytes"].get<uint64_t>()) + " bytes") != std::string::npos);
  }
}

TEST_CASE("a job without btf_cielab has no such key; bad values are a 400 naming the field") {
  const fs::path dir = scratch_dir("server-btf-cielab-plain");
  ServerProcess server(dir / "data", free_loopback_port());
  const std::string id = btfvq_ok(dir, "submit --server " + server.url() + " --db plain --synthetic tile:8 --name t");
  REQUIRE(follow(server.url(), id).back()["state"] == "succeeded");
  const json job = get_json(server.url(), "/v1/jobs/" + id);
  REQUIRE(job["results"].size() == 1);
  CHECK(job["results"][0]["report"].is_object());
  CHECK_FALSE(job["results"][0]["report"].contains("btf_cielab"));
  CHECK_FALSE(job["request"].contains("btf_cielab"));

  httplib::Client c(server.url());
  const json material = json::array({{{"source", {{"synthetic", {{"preset", "tile"}, {"size", 8}}}}}}});
  const std::vector<std::pair<json, std::string>> bad = {
      {{{"btf_cielab", "fast"}}, "btf_cielab"},
      {{{"btf_cielab", "0,100"}}, "btf_cielab"},
      {{{"btf_cielab", "30,-5"}}, "btf_cielab"},
      {{{"btf_cielab", 30}}, "btf_cielab"},
      {{{"btf_cielab", {{"resolution", 30}}}}, "btf_cielab"},
      {{{"target_btf_cielab", 0}}, "target_btf_cielab"},
      {{{"target_btf_cielab", "low"}}, "target_btf_cielab"},
      {{{"target_btf_cielab", 2}, {"target_mssim", 0.9}}, "exclude each other"},
      {{{"target_btf_cielab", 2}, {"quality", 60}}, "exclude each other"},
  };
  for (const auto& [fields, expected] : bad) {
    json request = {{"database", "bad"}, {"materials", material}};
    request.update(fields);
    CAPTURE(request.dump());
    auto r = c.Post("/v1/jobs", request.dump(), "application/json");
    REQUIRE(r);
    CHECK(r->status == 400);
    const json error = json::parse(r->body)["error"];
    CHECK(error["code"] == "invalid_request");
    CHECK(error["message"].get<std::string>().find(expected) != std::string::npos);
  }
  CHECK(get_json(server.url(), "/v1/jobs")["jobs"].size() == 1);  // none of them was queued
}
