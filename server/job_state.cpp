#include "server/job_state.h"

#include <btfvq/error.h>

namespace btfvq::server {
namespace {

// In the order of the enum; these are the words of the store, the API and the metrics.
const std::array<std::string, kJobStates.size()> kNames = {"queued", "running", "succeeded", "failed", "cancelled"};

}  // namespace

const std::string& to_string(JobState state) { return kNames[size_t(state)]; }

JobState parse_job_state(const std::string& name) {
  for (JobState s : kJobStates)
    if (to_string(s) == name) return s;
  throw CorruptError("'" + name + "' is not a job state");
}

}  // namespace btfvq::server
