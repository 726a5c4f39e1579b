// Delta downloads (issue 18 part 4): the real btfvq-server and the real `btfvq` CLI on 127.0.0.1.
// A database downloaded at version 1 is brought to version 2 (a second material added by a second
// job) by fetching only the new head and the new sections: the bytes transferred, counted by the
// client and by the server's /metrics, are fewer than the file's, and the result hashes to the
// server's sha256. A damaged local file, or one of no listed version, is downloaded in full.
#include <doctest/doctest.h>
#include <httplib.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "pipeline/format/database.h"
#include "pipeline/util/sha256.h"
#include "support/server_process.h"
#include "support/test_paths.h"

using namespace btfvq;
using namespace btfvq::test;
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

double bytes_served(const std::string& url) {
  httplib::Client c(url);
  auto r = c.Get("/metrics");
  REQUIRE(r);
  std::istringstream in(r->body);
  std::string line;
  const std::string name = "btfvq_bytes_served_total ";
  while (std::getline(in, line))
    if (line.rfind(name, 0) == 0) return std::stod(line.substr(name.size()));
  FAIL("no btfvq_bytes_served_total in /metrics");
  return -1;
}

// The number after "transferred" in the download's stdout line, and whether it says delta-from.
uint64_t transferred(const std::string& line) {
  const auto at = line.find(" transferred ");
  REQUIRE(at != std::string::npos);
  return std::stoull(line.substr(at + 13));
}

void run_job(const fs::path& dir, const std::string& s, const std::string& job_args) {
  const CliRun job = run_btfvq(dir, "submit " + s + " " + job_args);
  REQUIRE(job.status == 0);
  REQUIRE(run_btfvq(dir, "watch " + s + " " + job.out).status == 0);
}

}  // namespace

TEST_CASE("delta download: version 1 -> 2 fetches fewer bytes than the file; damaged local file: full download") {
  const fs::path dir = scratch_dir("delta-download");
  ServerProcess server(dir / "data", free_loopback_port());
  const std::string s = "--server " + server.url();
  const std::string out = (dir / "shop.btfdb").string();

  run_job(dir, s, "--db shop --synthetic wood:8 --name wood8");
  CliRun first = run_btfvq(dir, "download " + s + " shop --out " + out);
  REQUIRE(first.status == 0);
  const uint64_t size1 = fs::file_size(out);
  CHECK(transferred(first.out) == size1);
  CHECK(first.out.find("delta-from") == std::string::npos);

  // The same version again: nothing to fetch.
  CliRun again = run_btfvq(dir, "download " + s + " shop --out " + out);
  REQUIRE(again.status == 0);
  CHECK(transferred(again.out) == 0);
  CHECK(again.out.find("delta-from 1") != std::string::npos);

  run_job(dir, s, "--db shop --synthetic tile:8 --name tile8");
  const json info = get_json(server.url(), "/v1/databases/shop");
  REQUIRE(info["versions"].size() == 2);
  const json& v1 = info["versions"][0];
  const json& v2 = info["newest"];
  REQUIRE(v2["layout"].is_object());
  // The layout: version 2's file holds version 1's sections right after its own (longer) head.
  const uint64_t h1 = v1["layout"]["head_length"], h2 = v2["layout"]["head_length"];
  CHECK(v2["layout"]["prefixes"].size() == 2);
  CHECK(v2["layout"]["prefixes"][0]["end"].get<uint64_t>() - h2 == size1 - h1);
  CHECK(v2["layout"]["prefixes"][0]["sha256"] == v1["layout"]["prefixes"][0]["sha256"]);
  CHECK(v2["layout"]["prefixes"][1]["end"] == v2["size"]);

  const double served_before = bytes_served(server.url());
  CliRun delta = run_btfvq(dir, "download " + s + " shop --out " + out);
  REQUIRE(delta.status == 0);
  const double served = bytes_served(server.url()) - served_before;
  const uint64_t size2 = fs::file_size(out);
  const uint64_t sent = transferred(delta.out);
  MESSAGE("version 1: " << size1 << " bytes; version 2: " << size2 << " bytes, of which " << sent
                        << " transferred (server counted " << served << ")");
  CHECK(delta.out.find("delta-from 1") != std::string::npos);
  CHECK(size2 == v2["size"].get<uint64_t>());
  CHECK(sent < size2);
  CHECK(double(sent) == served);
  CHECK(sent == h2 + (size2 - v2["layout"]["prefixes"][0]["end"].get<uint64_t>()));
  CHECK(sha256_file(out) == v2["sha256"].get<std::string>());
  CHECK(read_database(out).materials.size() == 2);
  CHECK_FALSE(fs::exists(out + ".part"));

  // Back to version 1 by --version: a newer local file is no base; a full download of version 1.
  {
    const std::string old = (dir / "old.btfdb").string();
    fs::copy_file(out, old);
    CliRun r = run_btfvq(dir, "download " + s + " shop --version 1 --out " + old);
    REQUIRE(r.status == 0);
    CHECK(sha256_file(old) == v1["sha256"].get<std::string>());
    // ... and from there to version 2 by a delta again.
    CliRun up = run_btfvq(dir, "download " + s + " shop --out " + old);
    REQUIRE(up.status == 0);
    CHECK(up.out.find("delta-from 1") != std::string::npos);
    CHECK(sha256_file(old) == v2["sha256"].get<std::string>());
  }

  // A damaged local file (one byte of a section flipped) is no listed version: a full download.
  {
    std::fstream f(out, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(std::streamoff(size2 - 10));
    char c = 0;
    f.seekg(std::streamoff(size2 - 10));
    f.get(c);
    f.seekp(std::streamoff(size2 - 10));
    f.put(char(c ^ 0x5a));
  }
  REQUIRE(sha256_file(out) != v2["sha256"].get<std::string>());
  CliRun full = run_btfvq(dir, "download " + s + " shop --out " + out);
  REQUIRE(full.status == 0);
  CHECK(full.out.find("delta-from") == std::string::npos);
  CHECK(transferred(full.out) == size2);
  CHECK(sha256_file(out) == v2["sha256"].get<std::string>());

  // A file that is no database at all: a full download too.
  std::ofstream(out, std::ios::trunc) << "not a database";
  CliRun junk = run_btfvq(dir, "download " + s + " shop --out " + out);
  REQUIRE(junk.status == 0);
  CHECK(transferred(junk.out) == size2);
  CHECK(sha256_file(out) == v2["sha256"].get<std::string>());
}
