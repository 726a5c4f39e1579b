// The Slurm executor against a real single-node Slurm (munged + slurmctld + slurmd started here, as
// root, by scripts/slurm-single-node.sh with a generated slurm.conf): a two-material job publishes
// the local executor's bytes, also when an array element is cancelled while it runs (it is
// resubmitted); a cancelled job leaves no Slurm job behind. If Slurm cannot start, the test fails
// with the script's one line saying why.
#include <doctest/doctest.h>

#include <cstdlib>
#include <set>

#include "server/slurm_executor.h"
#include "server_fixture.h"

using namespace btfvq;
using namespace btfvq::test;

namespace {

std::string shell(const std::string& cmd) {
  std::string out;
  const int rc = run_command(cmd, &out);
  return rc == 0 ? out : "exit " + std::to_string(rc) + ": " + out;
}

std::vector<std::string> lines(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);)
    if (!l.empty()) out.push_back(l);
  return out;
}

// The single-node cluster of this test, stopped when the test ends.
struct Cluster {
  fs::path dir;
  std::string script = std::string(BTFVQ_SOURCE_DIR) + "/scripts/slurm-single-node.sh";
  std::string why;  // empty when up
  Cluster() {
    dir = scratch_dir("slurm-cluster");
    const std::string out = shell(script + " start " + dir.string());
    if (out.find("slurm: up") == std::string::npos) {
      why = lines(out).empty() ? "no output" : lines(out).back();
      return;
    }
    setenv("SLURM_CONF", (dir / "slurm.conf").c_str(), 1);
  }
  ~Cluster() { shell(script + " stop " + dir.string()); }
  std::string squeue(const std::string& args = "") { return shell("squeue --noheader --array " + args + " --format='%i %j %T'"); }
  // What a failure message needs: the node's state and reason, the queue, the daemons' last words.
  std::string report() {
    return "sinfo: " + shell("sinfo -N --noheader -o '%N %T %E'") + "squeue: " + squeue() + "slurmctld.log:\n" +
           shell("tail -n 25 " + (dir / "log/slurmctld.log").string()) + "slurmd.log:\n" +
           shell("tail -n 25 " + (dir / "log/slurmd.log").string());
  }
  // The job's final state within `seconds`; anything else fails with the cluster's report, so a
  // stuck or failed job says why instead of running into ctest's timeout.
  json wait_final(server::Service& service, const std::string& id, const std::string& state, double seconds) {
    return wait_state(service, id, state, seconds, [this] { return report(); });
  }
};

json two_materials(const std::string& database) {
  return {{"database", database},
          {"materials", json::array({{{"name", "leather"}, {"source", {{"synthetic", {{"preset", "leather"}, {"size", 32}, {"seed", 3}}}}}},
                                     {{"name", "wood"}, {"source", {{"synthetic", {{"preset", "wood"}, {"size", 32}, {"seed", 4}}}}}}})}};
}

struct Run {
  std::string sha256, id;
  json job;
};

server::SlurmSettings slurm_settings(const fs::path& root) {
  server::SlurmSettings s;
  s.partition = "btfvq";
  s.shared_folder = (root / "shared").string();
  s.tile_command = std::string(BTFVQ_BIN_DIR) + "/btfvq";
  s.tiles_per_element = 1;
  s.max_resubmits = 3;
  s.poll_interval_s = 0.2;
  return s;
}

}  // namespace

TEST_CASE("Slurm executor: a two-material job publishes the local bytes, a cancelled element is resubmitted, a cancelled job leaves no Slurm job") {
  Cluster cluster;
  if (!cluster.why.empty()) FAIL("single-node Slurm did not start: " << cluster.why);
  REQUIRE(cluster.squeue() == "");

  const fs::path root = scratch_dir("server-slurm");
  auto run = [&](const std::string& name, server::Executor executor, const std::function<void(const std::string&)>& meanwhile) {
    server::ServiceConfig config;
    config.data_dir = root / name;
    server::Service service(config, std::move(executor));
    service.start();
    const auto t = std::chrono::steady_clock::now();
    const std::string id = service.submit(two_materials("catalogue"))["id"];
    if (meanwhile) meanwhile(id);
    Run r;
    r.id = id;
    r.job = cluster.wait_final(service, id, "succeeded", name == "local" ? 120 : 240);  // ~10 s and ~45 s here
    r.sha256 = service.content("catalogue", std::nullopt).sha256;
    MESSAGE(name << ": " << std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count() << " s, sha256 " << r.sha256);
    service.stop();
    return r;
  };

  const Run local = run("local", server::make_pipeline_executor(), {});

  // Through Slurm; the first element seen running is cancelled (scancel JOBID_IDX).
  std::string cancelled_element;
  std::set<std::string> seen;  // "JOBID_IDX" of every element squeue listed
  struct Watcher {  // joined also when a failed check unwinds the test
    std::atomic<bool> done{false};
    std::thread thread;
    void stop() {
      done = true;
      if (thread.joinable()) thread.join();
    }
    ~Watcher() { stop(); }
  } watcher;
  const Run slurm = run("slurm", server::make_slurm_executor(slurm_settings(root)), [&](const std::string& id) {
    watcher.thread = std::thread([&, id] {
      while (!watcher.done) {
        for (const std::string& l : lines(cluster.squeue("--name=btfvq-" + id + "-0"))) {
          std::istringstream in(l);
          std::string element, name, state;
          in >> element >> name >> state;
          seen.insert(element);
          if (cancelled_element.empty() && state == "RUNNING") {
            cancelled_element = element;
            shell("scancel " + element);
          }
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
      }
    });
  });
  watcher.stop();
  CHECK(slurm.sha256 == local.sha256);
  REQUIRE(!cancelled_element.empty());
  // The cancelled element ran again under another Slurm job id, with the same array index.
  const std::string index = cancelled_element.substr(cancelled_element.find('_'));
  bool again = false;
  for (const std::string& e : seen) again = again || (e != cancelled_element && e.size() > index.size() &&
                                                      e.substr(e.size() - index.size()) == index &&
                                                      std::stol(e) > std::stol(cancelled_element));
  CHECK_MESSAGE(again, "no resubmission of " << cancelled_element << " seen");
  for (const auto& m : slurm.job["materials"]) MESSAGE(m.dump());
  CHECK(cluster.squeue() == "");
  CHECK(!fs::exists(root / "shared" / ("job-" + slurm.id)));

  // Cancelling a job whose tiles run on Slurm: afterwards squeue lists nothing.
  {
    server::ServiceConfig config;
    config.data_dir = root / "cancel";
    server::Service service(config, server::make_slurm_executor(slurm_settings(root)));
    service.start();
    const std::string id = service.submit(two_materials("cancelled"))["id"];
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (lines(cluster.squeue("--name=btfvq-" + id + "-0")).empty()) {
      const json job = service.job(id);
      if (std::chrono::steady_clock::now() > until || final_state(job))
        FAIL("no Slurm element of job " << id << " listed: " << job.dump() << "\n" << cluster.report());
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    service.cancel(id);
    cluster.wait_final(service, id, "cancelled", 60);
    CHECK(cluster.squeue() == "");
    CHECK(!fs::exists(root / "shared" / ("job-" + id)));
    service.stop();
  }
}
