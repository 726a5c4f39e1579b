// The service layer in-process: store durability, the per-database queue, cancellation, startup
// recovery, and validation that rejects bad jobs without changing anything.
#include "pipeline/encode/quality.h"
#include "server_fixture.h"

#include "server/errors.h"
#include "server/store.h"

#include <set>

using namespace btfvq;
using namespace btfvq::test;
using server::Service;
using server::ServiceConfig;

namespace {

ServiceConfig config_in(const fs::path& dir, int workers = 1) {
  ServiceConfig c;
  c.data_dir = dir;
  c.workers = workers;
  return c;
}

int index_of(const std::vector<std::string>& log, const std::string& entry) {
  for (size_t i = 0; i < log.size(); ++i)
    if (log[i] == entry) return int(i);
  FAIL("no '" << entry << "' in the log");
  return -1;
}

}  // namespace

TEST_CASE("job states have one name each, in the store and in the API") {
  std::set<std::string> names;
  for (server::JobState s : server::kJobStates) {
    names.insert(server::to_string(s));
    CHECK(server::parse_job_state(server::to_string(s)) == s);
    CHECK(json(s).get<server::JobState>() == s);
  }
  CHECK(names == std::set<std::string>{"queued", "running", "succeeded", "failed", "cancelled"});
  CHECK_THROWS_AS(server::parse_job_state("done"), CorruptError);
  CHECK_FALSE(server::is_final(server::JobState::queued));
  CHECK_FALSE(server::is_final(server::JobState::running));
  CHECK(server::is_final(server::JobState::cancelled));
}

TEST_CASE("the store keeps jobs, uploads and versions across a reopen") {
  const fs::path dir = scratch_dir("store");
  {
    server::Store store((dir / "s.sqlite").string());
    server::JobRecord job;
    job.id = "j1";
    job.database = "db";
    job.spec = {{"database", "db"}, {"materials", json::array()}};
    job.created = 100;
    CHECK(store.insert_job(job) == 1);
    job.id = "j2";
    CHECK(store.insert_job(job) == 2);
    store.set_job_state("j1", server::JobState::running, nullptr, 101, 0);
    store.set_job_progress("j1", {{"stage", "phase2"}, {"fraction", 0.5}});
    store.insert_upload({"u1", 42, "abc", "complete", 5});
    store.publish({"db", 1, "databases/db/v1.btfdb", "ff", 7, json::array({{{"name", "m"}}}), "j2", 9}, 10);
  }
  server::Store store((dir / "s.sqlite").string());
  const auto jobs = store.jobs();
  REQUIRE(jobs.size() == 2);
  CHECK(jobs[0].id == "j1");
  CHECK(jobs[0].state == server::JobState::running);
  CHECK(jobs[0].progress["stage"] == "phase2");
  CHECK(jobs[1].state == server::JobState::succeeded);
  CHECK(jobs[1].version == 1);
  CHECK(jobs[1].finished == 10);
  REQUIRE(store.upload("u1"));
  CHECK(store.upload("u1")->size == 42);
  CHECK_FALSE(store.upload("u2"));
  const auto versions = store.versions("db");
  REQUIRE(versions.size() == 1);
  CHECK(versions[0].materials[0]["name"] == "m");
  CHECK(store.requeue_running() == std::vector<std::string>{"j1"});
  CHECK(store.job("j1")->state == server::JobState::queued);
}

TEST_CASE("jobs on one database run in order; different databases run in parallel") {
  const fs::path dir = scratch_dir("queue");
  FakeCompressor fake;
  fake.step = std::chrono::milliseconds(15);
  Service service(config_in(dir, 2), fake.executor());
  service.start();
  const std::string a1 = service.submit(synthetic_job("alpha", "wool", 8, 1, "a1"))["id"];
  const std::string a2 = service.submit(synthetic_job("alpha", "wool", 8, 2, "a2"))["id"];
  const std::string b1 = service.submit(synthetic_job("beta", "wool", 8, 3, "b1"))["id"];
  for (const auto& id : {a1, a2, b1}) CHECK(wait_final(service, id)["state"] == "succeeded");
  const auto log = fake.events();
  CHECK(index_of(log, "end alpha a1") < index_of(log, "start alpha a2"));
  CHECK(index_of(log, "start beta b1") < index_of(log, "end alpha a1"));  // b1 did not wait for alpha
  CHECK(fake.max_running == 2);

  // Each success published a new version that holds everything before it.
  const json db = service.database("alpha");
  REQUIRE(db["versions"].size() == 2);
  CHECK(db["versions"][0]["materials"].size() == 1);
  CHECK(db["versions"][1]["materials"].size() == 2);
  const auto v2 = service.content("alpha", std::nullopt);
  CHECK(v2.version == 2);
  const std::string bytes = read_file(v2.path);
  CHECK(bytes.find("material a1") != std::string::npos);
  CHECK(bytes.find("material a2") != std::string::npos);
  CHECK(v2.sha256 == sha256_hex(bytes));
  CHECK(service.job(a2)["version"] == 2);
  CHECK(db["newest"]["ratio"].get<double>() > 0);
}

TEST_CASE("a failing job publishes nothing and records its error") {
  const fs::path dir = scratch_dir("fail");
  FakeCompressor fake;
  Service service(config_in(dir), fake.executor());
  service.start();
  const std::string id = service.submit(synthetic_job("gamma", "tile"))["id"];
  const json j = wait_final(service, id);
  CHECK(j["state"] == "failed");
  CHECK(j["error"]["code"] == "invalid_input");
  CHECK(j["error"]["message"].get<std::string>().find("tile preset") != std::string::npos);
  CHECK_THROWS_AS(service.database("gamma"), NotFoundError);
  CHECK(tree(dir / "databases").empty());
}

TEST_CASE("cancel stops a running job and removes a queued one from the queue") {
  const fs::path dir = scratch_dir("cancel");
  FakeCompressor fake;
  Service service(config_in(dir), fake.executor());
  service.start();
  const std::string running = service.submit(synthetic_job("delta", "foil", 8, 1, "r"))["id"];
  const std::string queued = service.submit(synthetic_job("delta", "wool", 8, 2, "q"))["id"];
  wait_state(service, running, "running");
  CHECK(service.cancel(queued)["state"] == "cancelled");
  service.cancel(running);
  const json r = wait_final(service, running);
  CHECK(r["state"] == "cancelled");
  CHECK(wait_final(service, queued)["state"] == "cancelled");
  CHECK_THROWS_AS(service.cancel(running), server::ConflictError);
  CHECK_THROWS_AS(service.cancel("nope"), NotFoundError);
  for (const auto& e : fake.events()) CHECK(e.find(" q") == std::string::npos);  // never started
  CHECK_THROWS_AS(service.database("delta"), NotFoundError);
  CHECK(tree(dir / "databases").empty());
}

TEST_CASE("a job left running by a killed server is re-queued and completes; leftovers are removed") {
  const fs::path dir = scratch_dir("recover");
  std::string id;
  {
    FakeCompressor fake;
    Service service(config_in(dir), fake.executor());  // not started: nothing runs
    id = service.submit(synthetic_job("eps", "wool", 8, 1, "m1"))["id"];
  }
  {  // What a kill -9 in the middle of the job leaves behind.
    server::Store store((dir / "btfvq.sqlite").string());
    store.set_job_state(id, server::JobState::running, nullptr, 1, 0);
    store.set_job_progress(id, {{"stage", "phase3"}, {"fraction", 0.7}});
  }
  fs::create_directories(dir / "databases" / "eps");
  write_file(dir / "databases" / "eps" / ("." + id + ".tmp"), "half a database");
  write_file(dir / "databases" / "eps" / "v1.btfdb", "renamed but never recorded");
  write_file(dir / "uploads" / ".u9.1234.part", "half an upload");
  write_file(dir / "uploads" / "u8.upload", "complete file, never recorded");

  FakeCompressor fake;
  Service service(config_in(dir), fake.executor());
  service.start();
  const json j = wait_final(service, id);
  CHECK(j["state"] == "succeeded");
  CHECK(j["version"] == 1);
  const auto files = tree(dir);
  CHECK(files.size() == 1);
  CHECK(files.count("databases/eps/v1.btfdb") == 1);
  const std::string bytes = read_file(dir / "databases" / "eps" / "v1.btfdb");
  CHECK(bytes.find("never recorded") == std::string::npos);
  CHECK(bytes.find("material m1") != std::string::npos);
}

TEST_CASE("stopping the service puts a running job back in the queue; the next start finishes it") {
  const fs::path dir = scratch_dir("shutdown");
  std::string id;
  {
    FakeCompressor fake;
    Service service(config_in(dir), fake.executor());
    service.start();
    id = service.submit(synthetic_job("zeta", "leather"))["id"];
    wait_state(service, id, "running");
    service.stop();  // leather waits for release(); stop() must still interrupt it
    fake.release();
  }
  {
    server::Store store((dir / "btfvq.sqlite").string());
    CHECK(store.job(id)->state == server::JobState::queued);
  }
  FakeCompressor fake;
  fake.release();
  Service service(config_in(dir), fake.executor());
  service.start();
  CHECK(wait_final(service, id)["state"] == "succeeded");
}

TEST_CASE("job validation names the field and changes nothing") {
  const fs::path dir = scratch_dir("validate");
  const fs::path inputs = scratch_dir("validate-inputs");
  fs::create_directories(inputs / "ok");
  write_file(inputs / "ok" / "sample.zip", tiny_sample_zip());
  const fs::path outside = scratch_dir("validate-outside");
  write_file(outside / "secret.zip", "secret");
  fs::create_symlink(outside / "secret.zip", inputs / "link.zip");

  FakeCompressor fake;
  ServiceConfig c = config_in(dir);
  c.input_root = inputs;
  Service service(c, fake.executor());  // not started, so accepted jobs stay queued and visible
  const auto before_files = tree(dir);

  struct Case {
    json body;
    std::string field;
  };
  auto with_source = [](json source) {
    return json{{"database", "d"}, {"materials", json::array({{{"source", source}}})}};
  };
  const std::vector<Case> input_errors = {
      {json::array(), "request body"},
      {{{"database", "d"}}, "materials"},
      {{{"database", 5}, {"materials", json::array()}}, "database"},
      {{{"database", "../x"}, {"materials", json::array()}}, "database"},
      {{{"database", "d"}, {"materials", json::array()}}, "materials"},
      {{{"database", "d"}, {"materials", json::array()}, {"extra", 1}}, "extra"},
      {synthetic_job("d", "wool", 0), "size"},
      {synthetic_job("d", "wool", 100000), "size"},
      {synthetic_job("d", "wool", 8, -1), "seed"},
      {synthetic_job("d", "no-such-preset"), "preset"},
      {with_source({{"synthetic", {{"preset", "wool"}, {"size", 8.5}}}}), "size"},
      {with_source({{"synthetic", {{"preset", "wool"}, {"size", "8"}}}}), "size"},
      {with_source({{"synthetic", {{"preset", "wool"}, {"size", 8}, {"colour", "red"}}}}), "colour"},
      {with_source({{"synthetic", {{"preset", "wool"}}}}), "size"},
      {with_source({{"upload", "u-missing"}}), "upload"},
      {with_source({{"upload", "u"}, {"path", "p"}}), "source"},
      {with_source({{"tape", "x"}}), "tape"},
      {with_source({{"path", "ok/missing.zip"}}), "path"},
      {{{"database", "d"}, {"materials", json::array({{{"source", {{"path", "ok/sample.zip"}}}, {"nmae", "x"}}})}}, "nmae"},
      {{{"database", "d"}, {"materials", json::array({{{"source", {{"path", "ok/sample.zip"}}}}})}, {"pipeline", 3}},
       "pipeline"},
      {{{"database", "d"}, {"materials", json::array({{{"source", {{"path", "ok/sample.zip"}}}}})}, {"quality", 101}},
       "quality"},
      {{{"database", "d"}, {"materials", json::array({{{"source", {{"path", "ok/sample.zip"}}}}})}, {"quality", "high"}},
       "quality"},
      {{{"database", "d"}, {"materials", json::array({{{"source", {{"path", "ok/sample.zip"}}}}})}, {"target_mssim", 1.5}},
       "target_mssim"},
      {{{"database", "d"}, {"materials", json::array({{{"source", {{"path", "ok/sample.zip"}}}}})}, {"quality", 60}, {"target_mssim", 0.9}},
       "exclude"},
      {{{"database", "d"}, {"materials", json::array({{{"source", {{"path", "ok/sample.zip"}}}}})}, {"target_btf_cielab", 0}},
       "target_btf_cielab"},
      {{{"database", "d"}, {"materials", json::array({{{"source", {{"path", "ok/sample.zip"}}}}})}, {"target_btf_cielab", 1}, {"target_mssim", 0.9}},
       "exclude"},
      {{{"database", "d"}, {"materials", json::array({{{"source", {{"path", "ok/sample.zip"}}}}})}, {"btf_cielab", "50;100"}},
       "btf_cielab"},
      {{{"database", "d"}, {"materials", json::array({{{"source", {{"path", "ok/sample.zip"}}}}})}, {"btf_cielab", true}},
       "btf_cielab"},
  };
  for (const auto& c : input_errors) {
    CAPTURE(c.body.dump());
    try {
      service.submit(c.body);
      FAIL("accepted");
    } catch (const InputError& e) {
      CHECK(std::string(e.what()).find(c.field) != std::string::npos);
    }
  }
  for (const std::string& path : std::vector<std::string>{"../validate-outside/secret.zip", (outside / "secret.zip").string(), "link.zip"}) {
    CAPTURE(path);
    CHECK_THROWS_AS(service.submit(with_source({{"path", path}})), server::ForbiddenError);
  }
  CHECK(service.jobs().empty());
  CHECK(tree(dir) == before_files);

  // The accepted form of the same request, for contrast.
  json accepted = with_source({{"path", "ok/sample.zip"}});
  accepted["pipeline"] = {{"grid", {{"n_beta", 13}}}};
  const json ok = service.submit(accepted);
  CHECK(ok["request"]["pipeline"]["grid"]["n_beta"] == 13);
  CHECK(ok["state"] == "queued");
  CHECK(ok["materials"][0] == "sample");
  CHECK(service.jobs().size() == 1);

  // "quality" resolves into the stored settings by the rule of `btfvq compress --quality`; the
  // request's own "pipeline" settings win over it.
  json tuned = with_source({{"path", "ok/sample.zip"}});
  tuned["quality"] = 80;
  tuned["pipeline"] = {{"thresholds", {{"ssim", {{"p1", 0.5}}}}}};
  const json q = service.submit(tuned);
  const json expected = quality_settings(80);
  CHECK(q["request"]["quality"] == 80);
  CHECK(q["request"]["pipeline"]["thresholds"]["ssim"]["p4"] == expected["thresholds"]["ssim"]["p4"]);
  CHECK(q["request"]["pipeline"]["schedule"]["compose_gain"] == expected["schedule"]["compose_gain"]);
  CHECK(q["request"]["pipeline"]["thresholds"]["ssim"]["p1"] == 0.5);
  json aimed = with_source({{"path", "ok/sample.zip"}});
  aimed["target_mssim"] = 0.85;
  CHECK(service.submit(aimed)["request"]["target_mssim"] == 0.85);
  json perceptual = with_source({{"path", "ok/sample.zip"}});
  perceptual["target_btf_cielab"] = 2.5;
  perceptual["btf_cielab"] = "50,";
  const json p = service.submit(perceptual)["request"];
  CHECK(p["target_btf_cielab"] == 2.5);
  CHECK(p["btf_cielab"] == "50,");
}

TEST_CASE("without an input root, server-side paths are refused") {
  FakeCompressor fake;
  Service service(config_in(scratch_dir("noroot")), fake.executor());
  json body = {{"database", "d"}, {"materials", json::array({{{"source", {{"path", "/etc/passwd"}}}}})}};
  CHECK_THROWS_AS(service.submit(body), server::ForbiddenError);
  CHECK(service.jobs().empty());
}
