#pragma once
// The states of a job. The code works with the enum; the names exist only where a state leaves the
// process: in the store's rows, in the JSON of the API and in the metrics' labels.
#include <nlohmann/json.hpp>

#include <array>
#include <string>

namespace btfvq::server {

enum class JobState { queued, running, succeeded, failed, cancelled };

inline constexpr std::array<JobState, 5> kJobStates = {JobState::queued, JobState::running, JobState::succeeded,
                                                       JobState::failed, JobState::cancelled};

const std::string& to_string(JobState state);
// Throws CorruptError for a name that is not a state (a store written by something else).
JobState parse_job_state(const std::string& name);

// Succeeded, failed and cancelled jobs never change again.
inline bool is_final(JobState s) {
  return s == JobState::succeeded || s == JobState::failed || s == JobState::cancelled;
}

inline void to_json(nlohmann::json& j, JobState s) { j = to_string(s); }
inline void from_json(const nlohmann::json& j, JobState& s) { s = parse_job_state(j.get<std::string>()); }

}  // namespace btfvq::server
