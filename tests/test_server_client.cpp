// The remote half of the `btfvq` CLI (the real binary) against a server on loopback, and the
// `btfvq-server` binary itself (flags, config errors, graceful stop on SIGTERM).
#include "server_fixture.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

using namespace btfvq;
using namespace btfvq::test;

namespace {

std::string cli() { return (bin_dir() / "btfvq").string(); }

std::string trim(std::string s) {
  while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
  return s;
}

// Runs the CLI with stdout to a file; returns (exit status, stdout, stdout+stderr).
struct Run {
  int status;
  std::string out, all;
};
Run run_cli(const fs::path& dir, const std::string& args, const std::string& env = "") {
  const fs::path out = dir / "stdout.txt";
  Run r;
  r.status = run_command("( " + env + " " + cli() + " " + args + " > " + out.string() + " )", &r.all);
  r.out = read_file(out);
  return r;
}



}  // namespace

TEST_CASE("submit, watch, status, ls and download through the CLI") {
  TestServer t("cli-flow");
  const fs::path dir = t.root;
  const std::string server = "--server " + t.url();

  auto submit = run_cli(dir, "submit " + server + " --db shop --synthetic wool:16 --name wool16 --seed 3");
  CAPTURE(submit.all);
  REQUIRE(submit.status == 0);
  const std::string id = trim(submit.out);
  CHECK(id.size() > 8);

  auto watch = run_cli(dir, "watch " + server + " " + id);
  CAPTURE(watch.all);
  CHECK(watch.status == 0);
  CHECK(watch.all.find("succeeded") != std::string::npos);

  auto status = run_cli(dir, "status " + server + " " + id + " --json");
  REQUIRE(status.status == 0);
  const json job = json::parse(status.out);
  CHECK(job["state"] == "succeeded");
  CHECK(job["materials"] == json::array({"wool16"}));
  CHECK(job["request"]["materials"][0]["source"]["synthetic"] == json{{"preset", "wool"}, {"size", 16}, {"seed", 3}});

  auto ls = run_cli(dir, "ls " + server);
  REQUIRE(ls.status == 0);
  CHECK(ls.out.find("shop") != std::string::npos);

  const std::string expected = read_file(t.service->content("shop", std::nullopt).path);
  auto download = run_cli(dir, "download " + server + " shop --out " + (dir / "shop.btfdb").string());
  CAPTURE(download.all);
  REQUIRE(download.status == 0);
  CHECK(read_file(dir / "shop.btfdb") == expected);
  CHECK_FALSE(fs::exists(dir / "shop.btfdb.part"));
  CHECK_FALSE(fs::exists(dir / "shop.btfdb.part.json"));
  CHECK(download.out.find(sha256_hex(expected)) != std::string::npos);
}

TEST_CASE("download resumes a partial file with a Range request and verifies the sha256") {
  TestServer t("cli-resume");
  const fs::path dir = t.root;
  const std::string server = "--server " + t.url();
  const std::string id = t.service->submit(synthetic_job("big", "wool", 64, 5, "m"))["id"];
  REQUIRE(wait_final(*t.service, id)["state"] == "succeeded");
  const std::string bytes = read_file(t.service->content("big", std::nullopt).path);
  const std::string sha = sha256_hex(bytes);
  REQUIRE(bytes.size() > 60000);
  const size_t half = bytes.size() / 2;
  const json meta = {{"database", "big"}, {"version", 1}, {"sha256", sha}, {"size", bytes.size()}};

  // A good partial file: only the rest is transferred.
  write_file(dir / "a.btfdb.part", bytes.substr(0, half));
  write_file(dir / "a.btfdb.part.json", meta.dump());
  const double before = metric(t.client().Get("/metrics")->body, "btfvq_bytes_served_total");
  auto r = run_cli(dir, "download " + server + " big --out " + (dir / "a.btfdb").string());
  CAPTURE(r.all);
  REQUIRE(r.status == 0);
  CHECK(read_file(dir / "a.btfdb") == bytes);
  const double after = metric(t.client().Get("/metrics")->body, "btfvq_bytes_served_total");
  CHECK(after - before == double(bytes.size() - half));
  CHECK(r.all.find("resumed") != std::string::npos);

  // A corrupted partial file fails verification, is thrown away, and the download starts over.
  write_file(dir / "b.btfdb.part", std::string(half, 'X'));
  write_file(dir / "b.btfdb.part.json", meta.dump());
  auto r2 = run_cli(dir, "download " + server + " big --out " + (dir / "b.btfdb").string());
  CAPTURE(r2.all);
  REQUIRE(r2.status == 0);
  CHECK(read_file(dir / "b.btfdb") == bytes);
  CHECK_FALSE(fs::exists(dir / "b.btfdb.part"));

  // A partial file longer than the database is not resumable: start over.
  write_file(dir / "c.btfdb.part", bytes + "trailing");
  write_file(dir / "c.btfdb.part.json", meta.dump());
  REQUIRE(run_cli(dir, "download " + server + " big --out " + (dir / "c.btfdb").string()).status == 0);
  CHECK(read_file(dir / "c.btfdb") == bytes);
}

TEST_CASE("submit uploads local files first; BTFVQ_SERVER stands in for --server") {
  TestServer t("cli-upload");
  const fs::path dir = t.root;
  const std::string& payload = tiny_sample_zip();
  write_file(dir / "sample.zip", payload);
  auto submit = run_cli(dir, "submit --db cars --upload " + (dir / "sample.zip").string() + " --name impalla",
                        "BTFVQ_SERVER=" + t.url());
  CAPTURE(submit.all);
  REQUIRE(submit.status == 0);
  // Not a terminal: the progress bar prints plain lines on stderr, and stdout holds only the id.
  CHECK(submit.all.find("upload sample.zip: 100%") != std::string::npos);
  CHECK(submit.out.find("upload") == std::string::npos);
  const json job = wait_final(*t.service, trim(submit.out));
  CHECK(job["state"] == "succeeded");
  const std::string upload = job["request"]["materials"][0]["source"]["upload"];
  CHECK(t.service->upload(upload)["sha256"] == sha256_hex(payload));
  const std::string db = read_file(t.service->content("cars", std::nullopt).path);
  CHECK(db.find("material impalla upload") != std::string::npos);
  CHECK(db.find(sha256_hex(payload)) != std::string::npos);

  CHECK(run_cli(dir, "submit --db cars --upload " + (dir / "missing.zip").string(), "BTFVQ_SERVER=" + t.url()).status == 2);
  CHECK(run_cli(dir, "submit --db cars --synthetic wool:16").status == 2);  // no server anywhere
}

TEST_CASE("watch exits non-zero for failed and cancelled jobs; bad submissions exit 2") {
  TestServer t("cli-fail");
  const fs::path dir = t.root;
  const std::string server = "--server " + t.url();
  const std::string failed = trim(run_cli(dir, "submit " + server + " --db x --synthetic tile:8").out);
  auto w1 = run_cli(dir, "watch " + server + " " + failed);
  CHECK(w1.status == 1);
  CHECK(w1.all.find("tile preset") != std::string::npos);

  const std::string endless = trim(run_cli(dir, "submit " + server + " --db y --synthetic foil:8").out);
  wait_state(*t.service, endless, "running");
  std::thread canceller([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    t.client().Delete("/v1/jobs/" + endless);
  });
  auto w2 = run_cli(dir, "watch " + server + " " + endless);
  canceller.join();
  CHECK(w2.status == 5);

  auto bad = run_cli(dir, "submit " + server + " --db x --synthetic velvet:8");
  CHECK(bad.status == 2);
  CHECK(bad.all.find("velvet") != std::string::npos);
  auto tiny = run_cli(dir, "submit " + server + " --db x --synthetic wool:0");
  CHECK(tiny.status == 2);
  CHECK(tiny.all.find("size") != std::string::npos);
  CHECK(run_cli(dir, "status " + server + " jnope").status == 4);
  CHECK(t.service->jobs().size() == 2);
}

TEST_CASE("the CLI sends BTFVQ_TOKEN") {
  server::HttpOptions options;
  options.token = "tok-123";
  TestServer t("cli-token", {}, options);
  auto denied = run_cli(t.root, "ls --server " + t.url());
  CHECK(denied.status != 0);
  CHECK(denied.all.find("401") != std::string::npos);
  CHECK(run_cli(t.root, "ls --server " + t.url(), "BTFVQ_TOKEN=tok-123").status == 0);
  CHECK(run_cli(t.root, "ls --server " + t.url() + " --token tok-123").status == 0);
}

TEST_CASE("btfvq-server: rejects bad config, serves, and stops cleanly on SIGTERM") {
  const fs::path dir = scratch_dir("server-binary");
  const std::string server = (bin_dir() / "btfvq-server").string();
  write_file(dir / "bad.json", R"({"listen": "127.0.0.1:0", "wrokers": 2})");
  std::string out;
  CHECK(run_command(server + " --config " + (dir / "bad.json").string() + " --data " + (dir / "d").string(), &out) == 2);
  CHECK(out.find("wrokers") != std::string::npos);
  CHECK(run_command(server + " --listen nonsense --data " + (dir / "d").string(), &out) == 2);
  CHECK(run_command(server + " --bogus 1", &out) == 2);

  const int port = free_loopback_port();
  const pid_t pid = ::fork();
  REQUIRE(pid >= 0);
  if (pid == 0) {
    const std::string listen = "127.0.0.1:" + std::to_string(port), data = (dir / "data").string();
    ::execl(server.c_str(), server.c_str(), "--listen", listen.c_str(), "--data", data.c_str(), "--workers", "2",
            static_cast<char*>(nullptr));
    ::_exit(127);
  }
  httplib::Client c("http://127.0.0.1:" + std::to_string(port));
  bool up = false;
  for (int i = 0; i < 500 && !up; ++i) {
    auto r = c.Get("/healthz");
    up = r && r->status == 200;
    if (!up) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  REQUIRE(up);
  auto m = c.Get("/metrics");
  REQUIRE(m);
  CHECK(metric(m->body, "btfvq_workers") == 2);
  ::kill(pid, SIGTERM);
  int status = 0;
  for (int i = 0; i < 500 && ::waitpid(pid, &status, WNOHANG) == 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  REQUIRE(WIFEXITED(status));
  CHECK(WEXITSTATUS(status) == 0);
  CHECK(fs::exists(dir / "data" / "btfvq.sqlite"));
}
