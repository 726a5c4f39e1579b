// A full disk (issue 21): the data directory on a real 4 MiB tmpfs that this test mounts (the tests
// run as root), filled by a filler file until the job's database write, an upload or a store write
// finds no space. The files are real, written by the real write_file_atomically; only the
// compressor is the FakeCompressor of server_fixture.h.
#include "server_fixture.h"

#include <fcntl.h>
#include <sys/mount.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "server/store.h"

using namespace btfvq;
using namespace btfvq::test;

namespace {

constexpr uint64_t kMiB = uint64_t(1) << 20;

// A tmpfs of 4 MiB at <scratch>/<name>/disk, unmounted by the destructor whatever the test did. A
// machine where it cannot be mounted fails the test: a full disk that was not tried is not a pass.
struct SmallDisk {
  fs::path dir;
  bool mounted = false;

  explicit SmallDisk(const std::string& name) {
    dir = scratch_dir(name) / "disk";
    fs::create_directories(dir);
    if (::mount("tmpfs", dir.c_str(), "tmpfs", MS_NOSUID | MS_NODEV, "size=4m,mode=0755") != 0)
      FAIL("cannot mount a 4 MiB tmpfs (mount -t tmpfs -o size=4m) at " << dir.string() << ": "
                                                                         << std::strerror(errno)
                                                                         << " (this test needs root)");
    mounted = true;
  }
  ~SmallDisk() {
    if (mounted && ::umount2(dir.c_str(), MNT_DETACH) != 0)
      MESSAGE("cannot unmount " << dir.string() << ": " << std::strerror(errno));
  }

  uint64_t free_bytes() const {
    struct statvfs s {};
    REQUIRE(::statvfs(dir.c_str(), &s) == 0);
    return uint64_t(s.f_bavail) * s.f_frsize;
  }

  // Grows the filler until at most `leave` bytes are free (0: until the disk refuses a byte).
  void fill(uint64_t leave) {
    const int fd = ::open(filler().c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
    REQUIRE(fd >= 0);
    const std::string chunk(64 * 1024, 'f');
    for (;;) {
      const uint64_t free = free_bytes();
      if (free <= leave) break;
      const ssize_t n = ::write(fd, chunk.data(), std::min<uint64_t>(chunk.size(), free - leave));
      if (n <= 0) {
        REQUIRE((n < 0 && errno == ENOSPC));
        break;
      }
    }
    ::close(fd);
    CHECK(free_bytes() <= leave + 4096);
  }
  void free_space() { fs::remove(filler()); }
  fs::path filler() const { return dir / "filler"; }
};

// Files that a write in progress or a failed write would leave: temporaries of AtomicFile and of
// whole uploads, and parts of resumable uploads.
std::vector<std::string> temporaries(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name.find(".tmp-") != std::string::npos || e.path().extension() == ".part") out.push_back(e.path().string());
  }
  return out;
}

bool healthy(const TestServer& t) {
  auto r = t.client().Get("/healthz");
  return r && r->status == 200;
}

}  // namespace

TEST_CASE("a job whose database write finds the disk full fails naming ENOSPC; the previous version stays; "
          "the next job succeeds once space is freed") {
  SmallDisk disk("full-disk-job");
  server::ServiceConfig config;
  config.data_dir = disk.dir / "data";
  TestServer t("full-disk-job-server", config);

  const json first = wait_final(*t.service, t.service->submit(synthetic_job("shop", "wool", 8, 1, "small"))["id"]);
  REQUIRE(first["state"] == "succeeded");
  const auto v1 = t.service->content("shop", std::nullopt);
  const std::string v1_sha = sha256_file(v1.path.string());
  REQUIRE(v1_sha == v1.sha256);

  // The fake writes 1 KiB per texel row of a material: 2048 rows do not fit in the 1 MiB left.
  disk.fill(kMiB);
  const std::string id = t.service->submit(synthetic_job("shop", "wool", 2048, 2, "big"))["id"];
  const json failed = wait_final(*t.service, id);
  CAPTURE(failed.dump());
  REQUIRE(failed["state"] == "failed");
  CHECK(failed["error"]["code"] == "no_space");
  const std::string message = failed["error"]["message"];
  CHECK(message.find("ENOSPC") != std::string::npos);
  CHECK(message.find("No space left on device") != std::string::npos);

  // The same over HTTP: the job's state and its event stream name it.
  auto c = t.client();
  auto state = c.Get("/v1/jobs/" + id);
  REQUIRE(state);
  CHECK(json::parse(state->body)["error"]["code"] == "no_space");
  auto events = c.Get("/v1/jobs/" + id + "/events");
  REQUIRE(events);
  CHECK(events->body.find("event: end") != std::string::npos);
  CHECK(events->body.find("no_space") != std::string::npos);
  CHECK(events->body.find("ENOSPC") != std::string::npos);

  // The previous version is still the one served, byte for byte, and nothing half-written is left.
  const auto still = t.service->content("shop", std::nullopt);
  CHECK(still.version == 1);
  CHECK(still.path == v1.path);
  CHECK(sha256_file(still.path.string()) == v1_sha);
  auto download = c.Get("/v1/databases/shop/content");
  REQUIRE(download);
  CHECK(download->status == 200);
  CHECK(sha256_hex(download->body) == v1_sha);
  CHECK(temporaries(t.data()) == std::vector<std::string>{});
  CHECK_FALSE(fs::exists(t.data() / server::DataDir::version("shop", 2)));
  CHECK(healthy(t));

  disk.free_space();
  const json again = wait_final(*t.service, t.service->submit(synthetic_job("shop", "wool", 2048, 2, "big"))["id"]);
  CAPTURE(again.dump());
  CHECK(again["state"] == "succeeded");
  CHECK(again["version"] == 2);
  const auto v2 = t.service->content("shop", std::nullopt);
  CHECK(v2.version == 2);
  CHECK(sha256_file(v2.path.string()) == v2.sha256);
  CHECK(sha256_file(v1.path.string()) == v1_sha);  // version 1 is kept beside it
  CHECK(temporaries(t.data()) == std::vector<std::string>{});
}

TEST_CASE("an upload that finds the disk full is refused with 507 no_space and leaves nothing; "
          "the server keeps running") {
  SmallDisk disk("full-disk-upload");
  server::ServiceConfig config;
  config.data_dir = disk.dir / "data";
  TestServer t("full-disk-upload-server", config);
  auto c = t.client();
  disk.fill(512 * 1024);

  std::string body(2 * kMiB, '\0');
  std::mt19937 rng(5);
  for (auto& ch : body) ch = char(rng());
  const std::string sha = sha256_hex(body);

  // Whole.
  auto whole = c.Put("/v1/uploads/whole", httplib::Headers{{"X-Sha256", sha}}, body, "application/octet-stream");
  REQUIRE(whole);
  CHECK(whole->status == 507);
  const json error = json::parse(whole->body)["error"];
  CHECK(error["code"] == "no_space");
  CHECK(error["message"].get<std::string>().find("ENOSPC") != std::string::npos);
  CHECK(c.Get("/v1/uploads/whole")->status == 404);
  CHECK(temporaries(t.data()) == std::vector<std::string>{});
  CHECK(healthy(t));

  // In one piece of a resumable upload: what fitted is kept to resume from once there is space.
  const std::string range = "bytes 0-" + std::to_string(body.size() - 1) + "/" + std::to_string(body.size());
  auto piece = c.Put("/v1/uploads/pieces", httplib::Headers{{"Content-Range", range}, {"X-Sha256", sha}}, body,
                     "application/octet-stream");
  REQUIRE(piece);
  CHECK(piece->status == 507);
  CHECK(json::parse(piece->body)["error"]["code"] == "no_space");
  const json partial = json::parse(c.Get("/v1/uploads/pieces")->body);
  CHECK(partial["state"] == "partial");
  const uint64_t received = partial["received"];
  CHECK(received < body.size());
  CHECK(healthy(t));

  disk.free_space();
  const std::string rest = "bytes " + std::to_string(received) + "-" + std::to_string(body.size() - 1) + "/" +
                           std::to_string(body.size());
  auto done = c.Put("/v1/uploads/pieces", httplib::Headers{{"Content-Range", rest}}, body.substr(received),
                    "application/octet-stream");
  REQUIRE(done);
  CHECK(done->status == 201);
  CHECK(json::parse(done->body)["sha256"] == sha);
  CHECK(read_file(t.data() / "uploads" / "pieces.upload") == body);
  CHECK(temporaries(t.data()) == std::vector<std::string>{});
}

TEST_CASE("a store write that finds the disk full is a no_space error naming ENOSPC; "
          "the store works once space is back") {
  SmallDisk disk("full-disk-store");
  server::Store store((disk.dir / "btfvq.sqlite").string());
  server::JobRecord job;
  job.id = "j1";
  job.database = "shop";
  job.spec = {{"note", std::string(kMiB, 'n')}};  // far more than the WAL holds: it must grow
  job.created = 1;
  disk.fill(0);
  try {
    store.insert_job(job);
    FAIL("the insert succeeded on a full disk");
  } catch (const NoSpaceError& e) {
    CHECK(e.code() == "no_space");
    CHECK(std::string(e.what()).find("ENOSPC") != std::string::npos);
  }
  CHECK_FALSE(store.job("j1"));
  disk.free_space();
  store.insert_job(job);
  REQUIRE(store.job("j1"));
  CHECK(store.job("j1")->spec == job.spec);
}

TEST_CASE("a job's end is recorded even when the disk is full for a moment (the record is retried)") {
  SmallDisk disk("full-disk-end");
  std::thread freer;
  // The job fills the disk and fails with an error too large for what is left of the store's log,
  // so its end cannot be recorded until the filler goes away a moment later.
  auto executor = [&](const server::JobSpec&, const std::string&, const std::string&, server::JobContext&) {
    disk.fill(0);
    freer = std::thread([&] {
      std::this_thread::sleep_for(std::chrono::milliseconds(300));
      disk.free_space();
    });
    throw InputError("the material is broken: " + std::string(2 * kMiB, 'e'));
  };
  server::ServiceConfig config;
  config.data_dir = disk.dir / "data";
  server::Service service(config, executor);
  service.start();
  spdlog::set_level(spdlog::level::off);  // the failed tries would log the 2 MiB message each
  const json job = wait_final(service, service.submit(synthetic_job("shop", "wool"))["id"]);
  spdlog::set_level(spdlog::level::warn);
  if (freer.joinable()) freer.join();
  // Without the retries the first failed record would end the worker (and the process); with them
  // the job's end is recorded once the filler is gone.
  CHECK(job["state"] == "failed");
  CHECK(job["error"]["code"] == "invalid_input");
  CHECK(job["error"]["message"].get<std::string>().size() > 2 * kMiB);
  CHECK(job["finished"].is_number());
  service.stop();
}
