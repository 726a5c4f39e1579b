// `btfvq watch`: follows a job's event stream with a progress bar until it ends.
// Exit status: 0 succeeded, 1 failed, 5 cancelled.
#include <chrono>
#include <iostream>
#include <thread>

#include "client/cli.h"
#include "client/http_client.h"
#include "client/progress_bar.h"
#include <btfvq/error.h>

namespace btfvq::cli {
namespace {
using nlohmann::json;

int exit_for(const json& job) {
  const std::string state = job.value("state", "");
  if (state == "succeeded") {
    std::cerr << "job " << job.value("id", "") << " succeeded: database " << job.value("database", "") << " version "
              << job.value("version", json(0)).dump() << "\n";
    return 0;
  }
  if (job.contains("error") && job["error"].is_object())
    std::cerr << "job " << job.value("id", "") << " " << state << ": " << job["error"].value("message", "") << "\n";
  return state == "cancelled" ? 5 : 1;
}

int run_watch(const Args& args) {
  if (args.positional.size() != 1) throw InputError("usage: btfvq watch --server URL JOB");
  const std::string id = args.positional[0];
  HttpClient client(remote_from(args));
  ProgressBar bar("job " + id);
  json last;
  // A dropped stream (server restart) is followed again; the job's state is the source of truth.
  for (int attempt = 0; attempt < 60; ++attempt) {
    try {
      client.events("/v1/jobs/" + id + "/events", [&](const std::string& event, const json& job) {
        last = job;
        bar.update(job.value("fraction", 0.0), job.value("state", "") + " " + describe_progress(job));
        return event != "end";
      });
    } catch (const Error& e) {
      if (e.code() != "connection") throw;
    }
    try {
      last = client.get_json("/v1/jobs/" + id);
    } catch (const Error& e) {
      if (e.code() != "connection") throw;
    }
    if (last.is_object() && (last.value("state", "") == "succeeded" || last.value("state", "") == "failed" ||
                             last.value("state", "") == "cancelled")) {
      bar.finish(last.value("state", ""));
      return exit_for(last);
    }
    std::this_thread::sleep_for(std::chrono::seconds(1));
  }
  throw Error("connection", "lost the event stream of job " + id);
}

CommandRegistrar reg({"watch", "watch --server URL JOB",
                      "follow a server job with a progress bar; exit 0 on success, 1 on failure, 5 if cancelled",
                      remote_options(), {}, run_watch});

}  // namespace
}  // namespace btfvq::cli
