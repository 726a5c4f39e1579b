// The REST API over real HTTP on 127.0.0.1 (random port), real SQLite in a scratch directory.
#include "server_fixture.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <regex>

#include "server/errors.h"
#include "server/http_errors.h"

using namespace btfvq;
using namespace btfvq::test;

namespace {

json body_json(const httplib::Result& r) {
  REQUIRE(r);
  return json::parse(r->body);
}

// The error shape every 4xx/5xx shares.
std::string error_message(const httplib::Result& r) {
  const json j = body_json(r);
  REQUIRE(j.contains("error"));
  CHECK(j["error"]["code"].is_string());
  return j["error"]["message"];
}

std::string publish_one(TestServer& t, const std::string& db, int size, int seed, const std::string& name) {
  auto c = t.client();
  auto r = c.Post("/v1/jobs", synthetic_job(db, "wool", size, seed, name).dump(), "application/json");
  REQUIRE(r);
  REQUIRE(r->status == 202);
  const std::string id = json::parse(r->body)["id"];
  CHECK(wait_final(*t.service, id)["state"] == "succeeded");
  return id;
}

// Sends raw bytes and closes the connection, as a client that dies mid-request.
void send_and_vanish(int port, const std::string& bytes) {
  const int fd = connect_loopback(port);
  size_t sent = 0;
  while (sent < bytes.size()) {
    const ssize_t n = ::send(fd, bytes.data() + sent, bytes.size() - sent, MSG_NOSIGNAL);
    REQUIRE(n > 0);
    sent += size_t(n);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  ::close(fd);
}


}  // namespace

TEST_CASE("every error reaches the client with the status and code of docs/api.md") {
  struct Case {
    std::exception_ptr error;
    int status;
    std::string code;
  };
  auto e = [](auto error) { return std::make_exception_ptr(error); };
  const std::vector<Case> cases = {
      {e(InputError("x")), 400, "invalid_input"},
      {e(InputError("x", "invalid_request")), 400, "invalid_request"},
      {e(InputError("x", "checksum_mismatch")), 400, "checksum_mismatch"},
      {e(ConfigError("x")), 400, "invalid_config"},
      {e(server::UnauthorizedError("x")), 401, "unauthorized"},
      {e(server::ForbiddenError("x")), 403, "forbidden"},
      {e(NotFoundError("x")), 404, "not_found"},
      {e(server::RequestTimeoutError("x")), 408, "request_timeout"},
      {e(server::ConflictError("x")), 409, "conflict"},
      {e(CancelledError("x")), 409, "cancelled"},
      {e(server::TooLargeError("x")), 413, "too_large"},
      {e(server::RangeNotSatisfiableError("x")), 416, "range_not_satisfiable"},
      {e(CorruptError("x")), 500, "corrupt"},
      {e(DeviceError("x")), 500, "device"},
      {e(Error("io", "x")), 500, "io"},
      {e(Error("store", "x")), 500, "store"},
      {e(Error("unavailable", "x")), 503, "unavailable"},
      {e(std::runtime_error("x")), 500, "internal"},
  };
  for (const auto& c : cases) {
    CAPTURE(c.code);
    const auto [status, body] = server::error_response(c.error);
    CHECK(status == c.status);
    CHECK(json::parse(body) == json{{"error", {{"code", c.code}, {"message", "x"}}}});
  }
  json never;
  try {
    never = json::parse("{");
  } catch (...) {
    const auto [status, body] = server::error_response(std::current_exception());
    CHECK(status == 400);
    CHECK(json::parse(body)["error"]["code"] == "invalid_json");
  }
  CHECK(server::code_of_status(404) == "not_found");
  CHECK(server::code_of_status(413) == "too_large");
  CHECK(server::code_of_status(416) == "range_not_satisfiable");
  CHECK(server::code_of_status(400) == "http_400");
  CHECK(server::code_of_status(409) == "http_409");
}

TEST_CASE("health, unknown routes and the error shape") {
  TestServer t("http-basic");
  auto c = t.client();
  auto h = c.Get("/healthz");
  REQUIRE(h);
  CHECK(h->status == 200);
  CHECK(body_json(h)["status"] == "ok");
  auto missing = c.Get("/v1/nothing-here");
  REQUIRE(missing);
  CHECK(missing->status == 404);
  error_message(missing);
  auto job = c.Get("/v1/jobs/jdoesnotexist");
  CHECK(job->status == 404);
  CHECK(error_message(job).find("jdoesnotexist") != std::string::npos);
  CHECK(c.Get("/v1/databases/none")->status == 404);
  CHECK(c.Get("/v1/databases/none/content")->status == 404);
  CHECK(c.Get("/v1/uploads/none")->status == 404);
  CHECK(c.Delete("/v1/jobs/none")->status == 404);
  auto events = c.Get("/v1/jobs/none/events");
  CHECK(events->status == 404);
  error_message(events);
}

TEST_CASE("a bearer token guards every endpoint but /healthz") {
  server::HttpOptions options;
  options.token = "s3cret";
  TestServer t("http-token", {}, options);
  auto anonymous = t.client();
  CHECK(anonymous.Get("/healthz")->status == 200);
  for (const char* path : {"/v1/jobs", "/v1/databases", "/metrics", "/v1/uploads/x", "/v1/jobs/x/events"}) {
    CAPTURE(path);
    auto r = anonymous.Get(path);
    REQUIRE(r);
    CHECK(r->status == 401);
    CHECK(body_json(r)["error"]["code"] == "unauthorized");
  }
  auto post = anonymous.Post("/v1/jobs", synthetic_job("d", "wool").dump(), "application/json");
  CHECK(post->status == 401);
  CHECK(t.client("wrong").Get("/v1/jobs")->status == 401);
  auto ok = t.client("s3cret").Get("/v1/jobs");
  CHECK(ok->status == 200);
  CHECK(body_json(ok)["jobs"].empty());  // the refused POST queued nothing
}

TEST_CASE("uploads: streamed, hashed, verified, limited; a dead client leaves nothing") {
  server::ServiceConfig config;
  config.max_upload_bytes = 100000;
  TestServer t("http-upload", config);
  auto c = t.client();
  const auto empty = tree(t.data());

  // sha256("abc") from FIPS 180-2, appendix B.1.
  const std::string abc_sha = "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad";
  auto bad_sha = c.Put("/v1/uploads/u1", httplib::Headers{{"X-Sha256", std::string(64, '0')}}, "abc",
                       "application/octet-stream");
  REQUIRE(bad_sha);
  CHECK(bad_sha->status == 400);
  CHECK(body_json(bad_sha)["error"]["code"] == "checksum_mismatch");
  CHECK(c.Get("/v1/uploads/u1")->status == 404);
  CHECK(tree(t.data()) == empty);

  auto good = c.Put("/v1/uploads/u1", httplib::Headers{{"X-Sha256", abc_sha}}, "abc", "application/octet-stream");
  REQUIRE(good);
  CHECK(good->status == 201);
  CHECK(body_json(good)["sha256"] == abc_sha);
  auto info = body_json(c.Get("/v1/uploads/u1"));
  CHECK(info["size"] == 3);
  CHECK(info["state"] == "complete");
  CHECK(read_file(t.data() / "uploads" / "u1.upload") == "abc");
  CHECK(c.Put("/v1/uploads/u1", "xyz", "application/octet-stream")->status == 409);
  CHECK(c.Put("/v1/uploads/.hidden", "xyz", "application/octet-stream")->status == 400);
  const auto after_one = tree(t.data());

  // Too large, announced by Content-Length: refused before reading.
  auto big = c.Put("/v1/uploads/u2", std::string(100001, 'x'), "application/octet-stream");
  REQUIRE(big);
  CHECK(big->status == 413);
  error_message(big);
  // Too large, chunked (no Content-Length): refused while streaming.
  auto big_stream = t.client().Put(
      "/v1/uploads/u3",
      [](size_t offset, httplib::DataSink& sink) {
        if (offset >= 150000) {
          sink.done();
          return true;
        }
        const std::string chunk(10000, 'y');
        return sink.write(chunk.data(), chunk.size());
      },
      "application/octet-stream");
  REQUIRE(big_stream);
  CHECK(big_stream->status == 413);
  CHECK(c.Get("/v1/uploads/u2")->status == 404);
  CHECK(c.Get("/v1/uploads/u3")->status == 404);
  CHECK(tree(t.data()) == after_one);

  // A client that dies half-way: the upload is never listed and its temporary file goes away.
  send_and_vanish(t.port, "PUT /v1/uploads/u4 HTTP/1.1\r\nHost: x\r\nContent-Length: 50000\r\n\r\n" +
                              std::string(20000, 'z'));
  for (int i = 0; i < 400 && t.client().Get("/v1/uploads/u4")->status != 404; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  CHECK(c.Get("/v1/uploads/u4")->status == 404);
  CHECK(tree(t.data()) == after_one);
  // And the id is free again.
  CHECK(c.Put("/v1/uploads/u4", "complete now", "application/octet-stream")->status == 201);
}

TEST_CASE("an uploaded sample can be used by a job") {
  TestServer t("http-upload-job");
  auto c = t.client();
  const std::string& payload = tiny_sample_zip();
  REQUIRE(c.Put("/v1/uploads/impalla", payload, "application/zip")->status == 201);
  json request = {{"database", "cars"}, {"materials", json::array({{{"source", {{"upload", "impalla"}}}}})}};
  auto r = c.Post("/v1/jobs", request.dump(), "application/json");
  REQUIRE(r->status == 202);
  const json j = wait_final(*t.service, body_json(r)["id"]);
  CHECK(j["state"] == "succeeded");
  const std::string db = read_file(t.service->content("cars", std::nullopt).path);
  CHECK(db.find("material impalla upload") != std::string::npos);
  CHECK(db.find("file-sha256 " + sha256_hex(payload)) != std::string::npos);
}

TEST_CASE("database downloads: length, ETag, sha256 header, ranges, versions") {
  TestServer t("http-download");
  publish_one(t, "shop", 16, 1, "first");
  publish_one(t, "shop", 24, 2, "second");
  auto c = t.client();
  const double served_before = metric(c.Get("/metrics")->body, "btfvq_bytes_served_total");

  auto full = c.Get("/v1/databases/shop/content");
  REQUIRE(full);
  CHECK(full->status == 200);
  const std::string bytes = full->body;
  CHECK(bytes == read_file(t.service->content("shop", std::nullopt).path));
  CHECK(full->get_header_value("Content-Length") == std::to_string(bytes.size()));
  const std::string sha = sha256_hex(bytes);
  CHECK(full->get_header_value("X-Content-Sha256") == sha);
  CHECK(full->get_header_value("ETag") == "\"" + sha + "\"");
  CHECK(full->get_header_value("X-Database-Version") == "2");
  CHECK(bytes.find("material second") != std::string::npos);

  auto slice = c.Get("/v1/databases/shop/content", httplib::Headers{{"Range", "bytes=100-1099"}});
  REQUIRE(slice);
  CHECK(slice->status == 206);
  CHECK(slice->body == bytes.substr(100, 1000));
  CHECK(slice->get_header_value("Content-Range") == "bytes 100-1099/" + std::to_string(bytes.size()));
  auto tail = c.Get("/v1/databases/shop/content", httplib::Headers{{"Range", "bytes=" + std::to_string(bytes.size() - 10) + "-"}});
  CHECK(tail->status == 206);
  CHECK(tail->body == bytes.substr(bytes.size() - 10));
  auto past = c.Get("/v1/databases/shop/content", httplib::Headers{{"Range", "bytes=" + std::to_string(bytes.size()) + "-"}});
  REQUIRE(past);
  CHECK(past->status == 416);
  CHECK(past->get_header_value("Content-Range") == "bytes */" + std::to_string(bytes.size()));
  CHECK(c.Get("/v1/databases/shop/content", httplib::Headers{{"Range", "bytes=banana"}})->status == 416);
  CHECK(c.Get("/v1/databases/shop/content", httplib::Headers{{"If-None-Match", "\"" + sha + "\""}})->status == 304);

  auto old = c.Get("/v1/databases/shop/content?version=1");
  REQUIRE(old);
  CHECK(old->status == 200);
  CHECK(old->get_header_value("X-Database-Version") == "1");
  CHECK(old->body.find("material second") == std::string::npos);
  CHECK(old->get_header_value("X-Content-Sha256") == sha256_hex(old->body));
  CHECK(c.Get("/v1/databases/shop/content?version=7")->status == 404);
  CHECK(c.Get("/v1/databases/shop/content?version=x")->status == 400);

  const double served_after = metric(c.Get("/metrics")->body, "btfvq_bytes_served_total");
  CHECK(served_after - served_before == double(bytes.size() + 1000 + 10 + old->body.size()));

  const json listing = body_json(c.Get("/v1/databases"));
  REQUIRE(listing["databases"].size() == 1);
  CHECK(listing["databases"][0]["name"] == "shop");
  CHECK(listing["databases"][0]["version"] == 2);
  CHECK(listing["databases"][0]["size"] == bytes.size());
  CHECK(listing["databases"][0]["materials"] == 2);
  const json detail = body_json(c.Get("/v1/databases/shop"));
  CHECK(detail["versions"].size() == 2);
  CHECK(detail["newest"]["materials"][1]["name"] == "second");
  // raw = 16*16*81*81*3 + 24*24*81*81*3 (what the fake reports), over the file size.
  CHECK(detail["newest"]["ratio"].get<double>() == doctest::Approx(double((16 * 16 + 24 * 24) * 81 * 81 * 3) / double(bytes.size())));
}

TEST_CASE("the event stream reports progress and ends at the final state") {
  TestServer t("http-events");
  auto c = t.client();
  auto r = c.Post("/v1/jobs", synthetic_job("ev", "leather").dump(), "application/json");
  const std::string id = body_json(r)["id"];
  std::vector<std::pair<std::string, json>> events;
  std::string buffer;
  std::thread releaser([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    t.fake.release();
  });
  auto stream = t.client().Get("/v1/jobs/" + id + "/events", [&](const char* data, size_t n) {
    buffer.append(data, n);
    size_t end;
    while ((end = buffer.find("\n\n")) != std::string::npos) {
      const std::string block = buffer.substr(0, end);
      buffer.erase(0, end + 2);
      std::smatch m;
      if (std::regex_search(block, m, std::regex("event: (\\w+)\ndata: (.*)")))
        events.emplace_back(m[1], json::parse(m[2].str()));
    }
    return true;
  });
  releaser.join();
  REQUIRE(stream);
  CHECK(stream->status == 200);
  CHECK(stream->get_header_value("Content-Type") == "text/event-stream");
  REQUIRE(events.size() >= 3);
  CHECK(events.back().first == "end");
  CHECK(events.back().second["state"] == "succeeded");
  CHECK(events.back().second["version"] == 1);
  bool saw_phase3 = false;
  double last_fraction = 0;
  for (size_t i = 0; i + 1 < events.size(); ++i) {
    CAPTURE(events[i].second.dump());
    CHECK(events[i].first == "progress");
    if (events[i].second["phase"] == 3) saw_phase3 = true;
    CHECK(events[i].second["fraction"].get<double>() >= last_fraction);
    last_fraction = events[i].second["fraction"];
  }
  CHECK(saw_phase3);
  // A stream opened after the end delivers the final state at once.
  auto again = t.client().Get("/v1/jobs/" + id + "/events");
  REQUIRE(again);
  CHECK(again->body.rfind("event: end\n", 0) == 0);
}

TEST_CASE("cancel over HTTP") {
  TestServer t("http-cancel");
  auto c = t.client();
  const std::string id = body_json(c.Post("/v1/jobs", synthetic_job("cx", "foil").dump(), "application/json"))["id"];
  wait_state(*t.service, id, "running");
  auto d = c.Delete("/v1/jobs/" + id);
  REQUIRE(d);
  CHECK(d->status == 202);
  CHECK(wait_final(*t.service, id)["state"] == "cancelled");
  CHECK(c.Delete("/v1/jobs/" + id)->status == 409);
  CHECK(c.Get("/v1/databases/cx")->status == 404);
}

TEST_CASE("bad job requests get a 4xx naming the field and change no state") {
  server::ServiceConfig config;
  config.input_root = scratch_dir("http-bad-inputs");
  fs::create_directories(config.input_root / "in");
  write_file(config.input_root / "in" / "a.zip", tiny_sample_zip());
  write_file(config.input_root / "in" / "junk.zip", "not an archive");
  write_archive(config.input_root / "in" / "evil.zip", {{"../evil/00000 tl000 pl000 tv000 pv000.jpg", "x"}});
  // A zip bomb: one entry that declares (and would expand to) more than the limit below.
  write_archive(config.input_root / "in" / "bomb.zip", {{"00000 tl000 pl000 tv000 pv000.jpg", std::string(24u << 20, '\0')}});
  config.max_expanded_bytes = 16u << 20;
  server::HttpOptions options;
  options.max_request_bytes = 4096;
  TestServer t("http-bad", config, options);
  auto c = t.client();
  publish_one(t, "keep", 8, 1, "kept");
  const auto files_before = tree(t.data());
  const std::string jobs_before = body_json(c.Get("/v1/jobs")).dump();

  struct Case {
    std::string body;
    int status;
    std::string mention;
  };
  const std::vector<Case> cases = {
      {"{", 400, "JSON"},
      {"{\"database\": \"d\", \"materials\": [{\"source\": {\"synthetic\": {\"preset\": \"wool\", \"size\": NaN}}}]}", 400, "JSON"},
      {"[]", 400, "object"},
      {R"({"database": "d", "materials": [], "priority": 1})", 400, "priority"},
      {R"({"database": "d", "materials": [{"source": {"synthetic": {"preset": "wool", "size": 8, "sede": 1}}}]})", 400, "sede"},
      {R"({"database": 7, "materials": []})", 400, "database"},
      {R"({"database": "d", "materials": [{"source": {"synthetic": {"preset": "wool", "size": 0}}}]})", 400, "size"},
      {R"({"database": "d", "materials": [{"source": {"synthetic": {"preset": "wool", "size": 100000}}}]})", 400, "size"},
      {R"({"database": "d", "materials": [{"source": {"synthetic": {"preset": "wool", "size": -3}}}]})", 400, "size"},
      {R"({"database": "d", "materials": [{"source": {"synthetic": {"preset": "wool", "size": 8, "seed": -1}}}]})", 400, "seed"},
      {R"({"database": "d", "materials": [{"source": {"synthetic": {"preset": "wool", "size": 8, "seed": 1e300}}}]})", 400, "seed"},
      {R"({"database": "d", "materials": [{"source": {"synthetic": {"preset": "velvet", "size": 8}}}]})", 400, "velvet"},
      {R"({"database": "d", "materials": [{"source": {"upload": "never-uploaded"}}]})", 400, "never-uploaded"},
      {R"({"database": "d", "materials": [{"source": {"path": "in/missing.zip"}}]})", 400, "missing.zip"},
      {R"({"database": "d", "materials": [{"source": {"path": "../../../../etc/passwd"}}]})", 403, "outside"},
      {R"({"database": "d", "materials": [{"source": {"path": "/etc/passwd"}}]})", 403, "outside"},
      {R"({"database": "keep", "materials": [{"name": "kept", "source": {"path": "in/a.zip"}}]})", 400, "kept"},
      {R"({"database": "d", "materials": [{"source": {"path": "in/a.zip"}}], "pipeline": []})", 400, "pipeline"},
      {R"({"database": "d", "materials": [{"source": {"path": "in/a.zip"}}], "pipeline": {"grid": {"n_alhpa": 3}}})", 400,
       "pipeline.grid.n_alhpa"},
      {R"({"database": "d", "materials": [{"source": {"path": "in/a.zip"}}], "pipeline": {"grid": {"n_beta": "11"}}})", 400,
       "pipeline.grid.n_beta"},
      {R"({"database": "d", "materials": [{"source": {"path": "in/a.zip"}}], "pipeline": {"grid": {"n_beta": 11.5}}})", 400,
       "pipeline.grid.n_beta"},
      {R"({"database": "d", "materials": [{"source": {"path": "in/a.zip"}}], "pipeline": {"thresholds": {"ssim": {"p4": -0.1}}}})",
       400, "thresholds.ssim.p4"},
      {R"({"database": "d", "materials": [{"source": {"path": "in/a.zip"}}], "quality": -1})", 400, "quality"},
      {R"({"database": "d", "materials": [{"source": {"path": "in/a.zip"}}], "quality": null})", 400, "quality"},
      {R"({"database": "d", "materials": [{"source": {"path": "in/junk.zip"}}]})", 400, "materials[0].source.path"},
      {R"({"database": "d", "materials": [{"source": {"path": "in/evil.zip"}}]})", 400, "'..'"},
      {R"({"database": "d", "materials": [{"source": {"path": "in/bomb.zip"}}]})", 400, "expands to"},
      {R"({"database": "d", "materials": [{"source": {"path": "in/a.zip"}}], "pad": ")" + std::string(5000, ' ') + "\"}",
       413, "exceeds"},
  };
  for (const auto& k : cases) {
    CAPTURE(k.body.substr(0, 200));
    auto r = c.Post("/v1/jobs", k.body, "application/json");
    REQUIRE(r);
    CHECK(r->status == k.status);
    CHECK(error_message(r).find(k.mention) != std::string::npos);
  }
  CHECK(body_json(c.Get("/v1/jobs")).dump() == jobs_before);
  CHECK(tree(t.data()) == files_before);
}

TEST_CASE("/metrics is Prometheus text") {
  TestServer t("http-metrics");
  publish_one(t, "m", 8, 1, "one");
  auto c = t.client();
  const std::string id = body_json(c.Post("/v1/jobs", synthetic_job("m2", "tile").dump(), "application/json"))["id"];
  wait_final(*t.service, id);
  auto r = c.Get("/metrics");
  REQUIRE(r);
  CHECK(r->status == 200);
  CHECK(r->get_header_value("Content-Type").rfind("text/plain", 0) == 0);
  const std::regex sample(R"([a-zA-Z_:][a-zA-Z0-9_:]*(\{[a-zA-Z_][a-zA-Z0-9_]*="[^"]*"(,[a-zA-Z_][a-zA-Z0-9_]*="[^"]*")*\})? -?[0-9.eE+-]+)");
  const std::regex comment(R"(# (HELP|TYPE) [a-zA-Z_:][a-zA-Z0-9_:]* .+)");
  std::istringstream in(r->body);
  std::string line;
  int samples = 0;
  while (std::getline(in, line)) {
    CAPTURE(line);
    CHECK((std::regex_match(line, sample) || std::regex_match(line, comment)));
    samples += line[0] != '#';
  }
  CHECK(samples >= 10);
  CHECK(metric(r->body, "btfvq_jobs{state=\"succeeded\"}") == 1);
  CHECK(metric(r->body, "btfvq_jobs{state=\"failed\"}") == 1);
  CHECK(metric(r->body, "btfvq_queue_length") == 0);
  CHECK(metric(r->body, "btfvq_stage_seconds_total{stage=\"phase2\"}") > 0);
}
