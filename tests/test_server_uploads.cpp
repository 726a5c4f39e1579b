// Resumable uploads (issue 21): PUT /v1/uploads/{id} with Content-Range against a real server on
// loopback, and the real client code (client/http_client.cpp, and the btfvq binary) continuing an
// upload that was cut off.
#include "server_fixture.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include "client/http_client.h"

using namespace btfvq;
using namespace btfvq::test;
using Clock = std::chrono::steady_clock;

namespace {

constexpr uint64_t kMiB = uint64_t(1) << 20;
constexpr uint64_t kPiece = 8 * kMiB;  // the client's piece size

std::string random_bytes(size_t n, uint32_t seed) {
  std::string s(n, '\0');
  std::mt19937 rng(seed);
  for (size_t i = 0; i < n; i += 4) {
    const uint32_t v = rng();
    for (size_t k = 0; k < 4 && i + k < n; ++k) s[i + k] = char(v >> (8 * k));
  }
  return s;
}

std::string range(uint64_t first, uint64_t length, uint64_t total) {
  return "bytes " + std::to_string(first) + "-" + std::to_string(first + length - 1) + "/" + std::to_string(total);
}

httplib::Result put_piece(httplib::Client& c, const std::string& id, const std::string& data, uint64_t first,
                          uint64_t length, const std::string& sha = "") {
  httplib::Headers h{{"Content-Range", range(first, length, data.size())}};
  if (!sha.empty()) h.emplace("X-Sha256", sha);
  return c.Put("/v1/uploads/" + id, h, data.substr(first, length), "application/octet-stream");
}

json body(const httplib::Result& r) {
  REQUIRE(r);
  return json::parse(r->body);
}

void send_all(int fd, const char* p, size_t n) {
  for (size_t sent = 0; sent < n;) {
    const ssize_t k = ::send(fd, p + sent, n - sent, MSG_NOSIGNAL);
    REQUIRE(k > 0);
    sent += size_t(k);
  }
}

// A client that sends the headers of a piece and `sent` bytes of its body, then goes away; returns
// once the server has let go of the upload (its bytes so far are what GET reports).
void cut_piece(const TestServer& t, const std::string& id, const std::string& data, uint64_t first, uint64_t length,
               uint64_t sent) {
  const int fd = connect_loopback(t.port);
  const std::string head = "PUT /v1/uploads/" + id + " HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Range: " +
                           range(first, length, data.size()) + "\r\nContent-Length: " + std::to_string(length) +
                           "\r\nContent-Type: application/octet-stream\r\n\r\n";
  send_all(fd, head.data(), head.size());
  send_all(fd, data.data() + first, sent);
  ::close(fd);
  // On a loaded machine the server may not even have accepted the connection yet, and a probing
  // PUT could then hold the id first and turn the piece away as "in progress" (this failed CI once).
  // So: first GET (which holds nothing) until the piece's bytes are on disk, then PUT probes at
  // offset 0 until the piece's handler has let go (409 upload_offset instead of 409 conflict).
  const auto until = Clock::now() + std::chrono::seconds(120);
  auto c = t.client();
  std::string last;
  bool on_disk = false;
  while (Clock::now() < until) {
    auto r = on_disk ? c.Put("/v1/uploads/" + id, httplib::Headers{{"Content-Range", range(0, 1, data.size())}}, "x",
                             "application/octet-stream")
                     : c.Get("/v1/uploads/" + id);
    REQUIRE(r);
    last = std::to_string(r->status) + " " + r->body;
    const json body = json::parse(r->body);
    if (!on_disk)
      on_disk = r->status == 200 && body.value("received", uint64_t(0)) == first + sent;
    else if (r->status == 409 && body["error"]["code"] == "upload_offset" && body["error"]["received"] == first + sent)
      return;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  FAIL("the server did not take in the " << sent << " bytes at " << first << " of " << id
                                         << "; the last probe answered " << last);
}

// A sample zip of about `size` bytes that a job accepts: the tiny sample's images plus a padding
// entry of random bytes (entries that are not images are ignored by the loader).
fs::path big_sample_zip(const std::string& name, size_t size) {
  const fs::path dir = scratch_dir(name);
  MeasuredSample s = make_bonn_sample(2, 2, Dynamic::LDR);
  for (size_t i = 0; i < s.ldr_data().size(); ++i) s.ldr_data()[i] = uint8_t(40 + i % 150);
  write_sample(s, (dir / "images").string());
  std::vector<std::pair<std::string, std::string>> entries;
  for (const auto& e : fs::recursive_directory_iterator(dir / "images"))
    if (e.is_regular_file())
      entries.emplace_back(fs::relative(e.path(), dir / "images").generic_string(), read_file(e.path()));
  entries.emplace_back("padding.bin", random_bytes(size, 99));
  const fs::path zip = dir / (name + ".zip");
  write_archive(zip, entries);
  return zip;
}

std::string upload_id_of(const std::string& sha) { return "s" + sha.substr(0, 32); }

size_t files_in(const fs::path& dir) {
  size_t n = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir)) ++n;
  return n;
}

// A TCP relay in front of the server that cuts the first `cuts` PUT connections once `cut_after`
// bytes went from the client to the server: a network that fails under a real client.
struct CuttingRelay {
  int target_port;
  uint64_t cut_after;
  std::atomic<int> cuts;
  int listen_fd = -1, port = 0;
  std::atomic<bool> stopping{false};
  std::thread acceptor;
  std::mutex mutex;
  std::vector<std::thread> connections;

  CuttingRelay(int target, uint64_t after, int n) : target_port(target), cut_after(after), cuts(n) {
    listen_fd = ::socket(AF_INET, SOCK_STREAM, 0);
    REQUIRE(listen_fd >= 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    REQUIRE(::bind(listen_fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
    REQUIRE(::listen(listen_fd, 16) == 0);
    socklen_t len = sizeof a;
    ::getsockname(listen_fd, reinterpret_cast<sockaddr*>(&a), &len);
    port = ntohs(a.sin_port);
    acceptor = std::thread([this] { accept_loop(); });
  }
  ~CuttingRelay() {
    stopping = true;
    acceptor.join();
    for (auto& t : connections) t.join();
    ::close(listen_fd);
  }
  std::string url() const { return "http://127.0.0.1:" + std::to_string(port); }

  void accept_loop() {
    while (!stopping) {
      pollfd p{listen_fd, POLLIN, 0};
      if (::poll(&p, 1, 50) <= 0) continue;
      const int client = ::accept(listen_fd, nullptr, nullptr);
      if (client < 0) continue;
      std::lock_guard lock(mutex);
      connections.emplace_back([this, client] { relay(client); });
    }
  }

  void relay(int client) {
    const int server = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in to{};
    to.sin_family = AF_INET;
    to.sin_port = htons(uint16_t(target_port));
    to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (server < 0 || ::connect(server, reinterpret_cast<sockaddr*>(&to), sizeof to) != 0) {
      ::close(client);
      if (server >= 0) ::close(server);
      return;
    }
    uint64_t upstream = 0;
    bool cutting = false;
    char buf[65536];
    while (!stopping) {
      pollfd p[2] = {{client, POLLIN, 0}, {server, POLLIN, 0}};
      if (::poll(p, 2, 50) <= 0) continue;
      if (p[0].revents) {
        ssize_t n = ::recv(client, buf, sizeof buf, 0);
        if (n <= 0) break;
        if (upstream == 0 && std::string(buf, size_t(std::min<ssize_t>(n, 4))) == "PUT ")
          cutting = cuts.fetch_sub(1) > 0;
        if (cutting && upstream + uint64_t(n) >= cut_after) n = ssize_t(cut_after - upstream);
        if (n > 0 && ::send(server, buf, size_t(n), MSG_NOSIGNAL) != n) break;
        upstream += uint64_t(n);
        if (cutting && upstream >= cut_after) break;
      }
      if (p[1].revents) {
        const ssize_t n = ::recv(server, buf, sizeof buf, 0);
        if (n <= 0 || ::send(client, buf, size_t(n), MSG_NOSIGNAL) != n) break;
      }
    }
    ::close(server);
    ::close(client);
  }
};

}  // namespace

TEST_CASE("an upload in pieces assembles byte for byte and is verified against the X-Sha256 of its first piece") {
  TestServer t("uploads-pieces");
  auto c = t.client();
  const std::string data = random_bytes(3 * kMiB + 12345, 1);
  const std::string sha = sha256_hex(data);
  const uint64_t piece = kMiB;

  uint64_t at = 0;
  while (at + piece < data.size()) {
    auto r = put_piece(c, "p1", data, at, piece, at == 0 ? sha : "");
    REQUIRE(r);
    CHECK(r->status == 200);
    at += piece;
    CHECK(body(r)["received"] == at);
    const json info = body(c.Get("/v1/uploads/p1"));
    CHECK(info["state"] == "partial");
    CHECK(info["received"] == at);
    CHECK(info["total"] == data.size());
    CHECK(info["sha256"] == sha);
  }
  auto last = put_piece(c, "p1", data, at, data.size() - at);
  REQUIRE(last);
  CHECK(last->status == 201);
  CHECK(body(last)["state"] == "complete");
  CHECK(body(last)["sha256"] == sha);
  CHECK(body(last)["size"] == data.size());
  CHECK(read_file(t.data() / "uploads" / "p1.upload") == data);
  CHECK(files_in(t.data() / "partial-uploads") == 0);
  const json info = body(c.Get("/v1/uploads/p1"));
  CHECK(info["state"] == "complete");
  CHECK(info["sha256"] == sha);
  // A complete upload is not reopened by another piece.
  CHECK(put_piece(c, "p1", data, 0, piece, sha)->status == 409);
  // A PUT without Content-Range is still a whole upload.
  auto whole = c.Put("/v1/uploads/w1", httplib::Headers{{"X-Sha256", sha256_hex("abc")}}, "abc", "text/plain");
  REQUIRE(whole);
  CHECK(whole->status == 201);
}

TEST_CASE("a piece that does not start where the upload stands gets 409 upload_offset with what was received") {
  TestServer t("uploads-offset");
  auto c = t.client();
  const std::string data = random_bytes(2 * kMiB, 2);
  const std::string sha = sha256_hex(data);

  // A new upload stands at 0; its first piece must name the whole file's sha256.
  auto early = put_piece(c, "o1", data, kMiB, kMiB, sha);
  REQUIRE(early);
  CHECK(early->status == 409);
  CHECK(body(early)["error"]["code"] == "upload_offset");
  CHECK(body(early)["error"]["received"] == 0);
  auto no_sha = put_piece(c, "o1", data, 0, kMiB);
  REQUIRE(no_sha);
  CHECK(no_sha->status == 400);
  CHECK(body(no_sha)["error"]["message"].get<std::string>().find("X-Sha256") != std::string::npos);
  CHECK(c.Get("/v1/uploads/o1")->status == 404);

  REQUIRE(put_piece(c, "o1", data, 0, kMiB / 2, sha)->status == 200);
  for (uint64_t wrong : {uint64_t(0), uint64_t(kMiB / 4), uint64_t(kMiB)}) {
    auto r = put_piece(c, "o1", data, wrong, kMiB / 4, sha);
    REQUIRE(r);
    CHECK(r->status == 409);
    CHECK(body(r)["error"]["code"] == "upload_offset");
    CHECK(body(r)["error"]["received"] == kMiB / 2);
  }
  // Malformed ranges and a body of another length than the range are refused; nothing changes.
  for (const std::string bad : {"bytes 5-4/10", "bytes 0-10/10", "bytes=0-1/10", "bytes 0-1/*", "bytes a-b/c"}) {
    auto r = c.Put("/v1/uploads/o1", httplib::Headers{{"Content-Range", bad}}, "xx", "application/octet-stream");
    REQUIRE(r);
    CAPTURE(bad);
    CHECK(r->status == 400);
  }
  auto short_body = c.Put("/v1/uploads/o1", httplib::Headers{{"Content-Range", range(kMiB / 2, 10, data.size())}},
                          "12345", "application/octet-stream");
  REQUIRE(short_body);
  CHECK(short_body->status == 400);
  auto other_total = c.Put("/v1/uploads/o1", httplib::Headers{{"Content-Range", range(kMiB / 2, 5, 4 * kMiB)}}, "12345",
                           "application/octet-stream");
  REQUIRE(other_total);
  CHECK(other_total->status == 409);
  CHECK(body(c.Get("/v1/uploads/o1"))["received"] == kMiB / 2);
  // The answer's `received` is where the piece that completes it starts.
  auto rest = put_piece(c, "o1", data, kMiB / 2, data.size() - kMiB / 2);
  REQUIRE(rest);
  CHECK(rest->status == 201);
  CHECK(read_file(t.data() / "uploads" / "o1.upload") == data);
}

TEST_CASE("a piece-wise upload that does not hash to its X-Sha256 gets 400 checksum_mismatch and is removed") {
  TestServer t("uploads-mismatch");
  auto c = t.client();
  const std::string data = random_bytes(kMiB + 7, 3);
  const std::string wrong = sha256_hex("something else");
  REQUIRE(put_piece(c, "m1", data, 0, kMiB, wrong)->status == 200);
  auto last = put_piece(c, "m1", data, kMiB, 7);
  REQUIRE(last);
  CHECK(last->status == 400);
  CHECK(body(last)["error"]["code"] == "checksum_mismatch");
  CHECK(c.Get("/v1/uploads/m1")->status == 404);
  CHECK(files_in(t.data() / "partial-uploads") == 0);
  CHECK(files_in(t.data() / "uploads") == 0);
  // The id starts over at 0.
  CHECK(body(put_piece(c, "m1", data, kMiB, 7, wrong))["error"]["received"] == 0);
}

TEST_CASE("an upload cut off at half is continued by the client from what the server received; "
          "the job built from it succeeds on the verified file") {
  TestServer t("uploads-resume");
  const fs::path zip = big_sample_zip("resume-sample", 20 * kMiB);
  const std::string data = read_file(zip);
  const std::string sha = sha256_hex(data);
  const std::string id = upload_id_of(sha);
  REQUIRE(data.size() > 2 * kPiece);

  // The first piece arrives; the second is cut off after 3 MiB of its 8.
  auto c = t.client();
  REQUIRE(put_piece(c, id, data, 0, kPiece, sha)->status == 200);
  cut_piece(t, id, data, kPiece, kPiece, 3 * kMiB);
  const json partial = body(c.Get("/v1/uploads/" + id));
  CHECK(partial["state"] == "partial");
  const uint64_t received = partial["received"];
  CHECK(received == kPiece + 3 * kMiB);

  cli::HttpClient client(cli::Remote{t.url(), ""});
  uint64_t last_progress = 0;
  const cli::UploadResult up =
      client.upload_file(id, zip.string(), sha, [&](uint64_t done, uint64_t) { last_progress = done; });
  CHECK(up.resumed_from == received);
  CHECK(up.bytes_sent == data.size() - received);  // only the rest, nothing sent again
  CHECK(up.bytes_sent < data.size());
  CHECK(up.retries == 0);
  CHECK(last_progress == data.size());
  CHECK(up.record["state"] == "complete");
  CHECK(up.record["sha256"] == sha);
  CHECK(read_file(t.data() / "uploads" / (id + ".upload")) == data);
  CHECK(files_in(t.data() / "partial-uploads") == 0);

  const json job = t.service->submit(
      {{"database", "resumed"}, {"materials", json::array({{{"name", "big"}, {"source", {{"upload", id}}}}})}});
  const json done = wait_final(*t.service, job["id"]);
  CAPTURE(done.dump());
  CHECK(done["state"] == "succeeded");
  const std::string db = read_file(t.service->content("resumed", std::nullopt).path);
  CHECK(db.find("material big upload") != std::string::npos);
  CHECK(db.find("file-sha256 " + sha) != std::string::npos);

  // Asked again, the client finds the complete upload and sends nothing.
  const cli::UploadResult again = client.upload_file(id, zip.string(), sha, nullptr);
  CHECK(again.existed);
  CHECK(again.bytes_sent == 0);
}

TEST_CASE("the client retries a piece cut off by the network and continues where the server stands") {
  TestServer t("uploads-retry");
  const std::string data = random_bytes(20 * kMiB, 4);
  const fs::path file = t.root / "data.bin";
  write_file(file, data);
  const std::string sha = sha256_hex(data);
  // The first two PUT connections die after 5 MiB of request: the first piece is cut in its body;
  // the second is the retry, which gets 5 MiB further.
  CuttingRelay relay(t.port, 5 * kMiB, 2);
  cli::HttpClient client(cli::Remote{relay.url(), ""});
  cli::UploadOptions options;
  options.first_pause = std::chrono::milliseconds(20);
  const cli::UploadResult up = client.upload_file(upload_id_of(sha), file.string(), sha, nullptr, options);
  CHECK(up.retries >= 2);
  CHECK(up.record["sha256"] == sha);
  CHECK(read_file(t.data() / "uploads" / (upload_id_of(sha) + ".upload")) == data);
  // What was re-sent is at most what the cut connections carried past the server's last fsync: here
  // nothing, since every byte that reached the server was kept.
  CHECK(up.bytes_sent >= data.size());
  CHECK(up.bytes_sent < data.size() + 2 * kPiece);
}

TEST_CASE("a partial upload left alone longer than upload_abandon_after_s is removed") {
  server::ServiceConfig config;
  config.upload_abandon_after_s = 1;
  TestServer t("uploads-abandon", config);
  auto c = t.client();
  const std::string data = random_bytes(kMiB, 5);
  const auto sent = Clock::now();
  REQUIRE(put_piece(c, "a1", data, 0, kMiB / 2, sha256_hex(data))->status == 200);
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  CHECK(body(c.Get("/v1/uploads/a1"))["state"] == "partial");  // not yet: younger than 1 s
  const auto until = sent + std::chrono::seconds(10);
  while (Clock::now() < until && c.Get("/v1/uploads/a1")->status != 404)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  const double after = std::chrono::duration<double>(Clock::now() - sent).count();
  CHECK(c.Get("/v1/uploads/a1")->status == 404);
  CHECK(after >= 1.0);
  CHECK(after < 5.0);
  CHECK(files_in(t.data() / "partial-uploads") == 0);
  // The id starts over.
  CHECK(body(put_piece(c, "a1", data, kMiB / 2, kMiB / 2))["error"]["received"] == 0);
}

TEST_CASE("at startup, halves of partial uploads are removed and complete pairs kept") {
  const fs::path root = scratch_dir("uploads-leftovers");
  const fs::path partial = root / "data" / "partial-uploads";
  fs::create_directories(partial);
  write_file(partial / "alone.part", "bytes without a description");
  write_file(partial / "orphan.json", R"({"id": "orphan", "total": 10, "sha256": "00"})");
  write_file(partial / ".kept.tmp-1-2.json", "a temporary");
  write_file(partial / "kept.part", "12345");
  write_file(partial / "kept.json", json{{"id", "kept"}, {"total", 10}, {"sha256", std::string(64, 'a')}}.dump());
  server::ServiceConfig config;
  config.data_dir = root / "data";
  TestServer t("uploads-leftovers-server", config);
  CHECK_FALSE(fs::exists(partial / "alone.part"));
  CHECK_FALSE(fs::exists(partial / "orphan.json"));
  CHECK_FALSE(fs::exists(partial / ".kept.tmp-1-2.json"));
  CHECK(files_in(partial) == 2);
  const json kept = body(t.client().Get("/v1/uploads/kept"));
  CHECK(kept["state"] == "partial");
  CHECK(kept["received"] == 5);
  CHECK(kept["total"] == 10);
}

TEST_CASE("btfvq submit --upload of a sample over 20 MiB continues a cut-off upload and submits the job") {
  TestServer t("uploads-cli");
  const fs::path zip = big_sample_zip("cli-sample", 20 * kMiB);
  const std::string data = read_file(zip);
  const std::string sha = sha256_hex(data);
  const std::string id = upload_id_of(sha);
  auto c = t.client();
  REQUIRE(put_piece(c, id, data, 0, kPiece, sha)->status == 200);
  cut_piece(t, id, data, kPiece, kPiece, kMiB);

  const std::string cli = (bin_dir() / "btfvq").string();
  const fs::path out = t.root / "stdout.txt";
  std::string all;
  // stdout (the job id) to a file, stderr (the progress bar) to `all`, as test_server_client runs the CLI.
  const int status = run_command("( " + cli + " submit --server " + t.url() + " --db cli --upload " + zip.string() +
                                     " --name big > " + out.string() + " )",
                                 &all);
  CAPTURE(all);
  REQUIRE(status == 0);
  CHECK(all.find("uploaded as " + id) != std::string::npos);
  CHECK(all.find("resumed at") != std::string::npos);
  std::string job_id = read_file(out);
  while (!job_id.empty() && job_id.back() == '\n') job_id.pop_back();
  const json done = wait_final(*t.service, job_id);
  CAPTURE(done.dump());
  CHECK(done["state"] == "succeeded");
  CHECK(done["request"]["materials"][0]["source"]["upload"] == id);
  CHECK(t.service->upload(id)["sha256"] == sha);
  CHECK(read_file(t.service->content("cli", std::nullopt).path).find("file-sha256 " + sha) != std::string::npos);

  // The same command again finds the upload on the server.
  std::string second;
  REQUIRE(run_command("( " + cli + " submit --server " + t.url() + " --db cli2 --upload " + zip.string() + " > " +
                          out.string() + " )",
                      &second) == 0);
  CHECK(second.find("already on the server as " + id) != std::string::npos);
  std::string second_job = read_file(out);
  while (!second_job.empty() && second_job.back() == '\n') second_job.pop_back();
  CHECK(wait_final(*t.service, second_job)["state"] == "succeeded");
}
