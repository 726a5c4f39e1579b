#pragma once
// The schema of a job request (POST /v1/jobs, docs/api.md): validation into the normalized request
// that is stored with the job, and the JobSpec that the executor gets from a stored job.
#include <nlohmann/json.hpp>

#include <cstdint>
#include <filesystem>
#include <string>

#include "server/data_dir.h"
#include "server/executor.h"
#include "server/store.h"

namespace btfvq::server {

// Names of databases, materials and uploads end up in file names and URLs: 1-64 of [A-Za-z0-9._-],
// starting alphanumeric.
bool valid_name(const std::string& s);

class JobRequests {
 public:
  // Server-side paths must lie under `input_root` (empty: they are refused); archives may expand to
  // `max_expanded_bytes` at most.
  JobRequests(Store& store, DataDir data, std::filesystem::path input_root, uint64_t max_expanded_bytes);

  // The normalized request of job `id`: names defaulted, server-side paths resolved. Throws
  // InputError naming the field (ForbiddenError for a path outside the input root) before anything
  // changes; the samples are checked now, so that bad input is a 400 and not a failed job.
  nlohmann::json validate(const nlohmann::json& request, const std::string& id) const;
  // What the executor gets from a stored job.
  JobSpec spec(const JobRecord& job) const;

 private:
  struct Source {
    nlohmann::json normalized;
    std::string default_name;
  };
  nlohmann::json material(const nlohmann::json& m, const std::string& where) const;
  Source upload_source(const nlohmann::json& source, const std::string& where) const;
  Source path_source(const nlohmann::json& source, const std::string& where) const;
  Source synthetic_source(const nlohmann::json& source, const std::string& where) const;
  void check_sample(const std::filesystem::path& file, const std::string& field) const;
  std::filesystem::path resolve_input_path(const std::string& given, const std::string& field) const;

  Store& store_;
  DataDir data_;
  std::filesystem::path input_root_;
  uint64_t max_expanded_bytes_;
};

}  // namespace btfvq::server
