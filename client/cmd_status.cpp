// `btfvq status`: one look at a job on the server.
#include <iostream>

#include "client/cli.h"
#include "client/http_client.h"
#include <btfvq/error.h>

namespace btfvq::cli {
namespace {

int run_status(const Args& args) {
  if (args.positional.size() != 1) throw InputError("usage: btfvq status --server URL JOB [--json]");
  HttpClient client(remote_from(args));
  const auto job = client.get_json("/v1/jobs/" + args.positional[0]);
  if (args.has("json")) {
    std::cout << job.dump(2) << "\n";
    return 0;
  }
  std::cout << "job       " << job.value("id", "") << "\n"
            << "database  " << job.value("database", "") << "\n"
            << "state     " << job.value("state", "") << "\n"
            << "progress  " << int(job.value("fraction", 0.0) * 100) << "% " << describe_progress(job) << "\n"
            << "elapsed   " << int(job.value("elapsed_s", 0.0)) << " s\n";
  if (job.contains("version") && job["version"].is_number()) std::cout << "version   " << job["version"] << "\n";
  if (job.contains("error") && job["error"].is_object())
    std::cout << "error     " << job["error"].value("code", "") << ": " << job["error"].value("message", "") << "\n";
  return 0;
}

CommandRegistrar reg({"status", "status --server URL JOB [--json]", "show the state and progress of a server job",
                      remote_options(), {{"json", "", "print the job as JSON"}}, run_status});

}  // namespace
}  // namespace btfvq::cli
