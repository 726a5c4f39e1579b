// The memory a finished job freed goes back to the system (bench/bench_soak.py found the server's
// resident memory growing 55% over a 10-minute soak of 31 small jobs: glibc kept what the
// compressions freed in its arenas). A job that allocates 96 MiB in small blocks, pins one block
// above them and frees the rest leaves that memory free but resident unless the server trims.
#include "server_fixture.h"

#include <cstring>
#include <fstream>

using namespace btfvq;
using namespace btfvq::test;

namespace {

// RssAnon of this process in KiB.
long rss_anon_kb() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("RssAnon:", 0) == 0) return std::stol(line.substr(8));
  return -1;
}

std::vector<std::unique_ptr<char[]>> pinned;  // above the freed blocks, alive until the process ends

}  // namespace

TEST_CASE("the memory a job freed is given back to the system when the job ends") {
#ifndef __GLIBC__
  return;
#endif
  const fs::path root = scratch_dir("server-memory");
  server::ServiceConfig config;
  config.data_dir = root / "data";
  long during = 0;
  auto executor = [&](const server::JobSpec&, const std::string&, const std::string&, server::JobContext&) {
    std::vector<std::unique_ptr<char[]>> blocks;
    for (int i = 0; i < 96 * 1024; ++i) {
      blocks.emplace_back(new char[1000]);
      std::memset(blocks.back().get(), i, 1000);  // resident
    }
    pinned.emplace_back(new char[1000]);  // keeps the heap's top above the freed blocks
    during = rss_anon_kb();
    blocks.clear();
    throw InputError("this job only allocates");
  };
  server::Service service(config, executor);
  service.start();
  const long before = rss_anon_kb();
  const json job = service.submit(synthetic_job("mem", "wool"));
  CHECK(wait_final(service, job["id"])["state"] == "failed");
  std::this_thread::sleep_for(std::chrono::milliseconds(200));  // the trim follows the job's end
  const long after = rss_anon_kb();
  service.stop();
  MESSAGE("RssAnon before " << before << " KiB, during the job " << during << " KiB, after " << after << " KiB");
  CHECK(during - before > 90 * 1024);
  CHECK(after - before < 24 * 1024);
}
