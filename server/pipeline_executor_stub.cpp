// Stand-ins for the pipeline-backed pieces of the server until the compressor library links in
// this branch. The integrator deletes this file and renames pipeline_executor.cpp.pending to
// pipeline_executor.cpp (same three functions, backed by compress_material()).
#include "pipeline/error.h"
#include "server/executor.h"

namespace btfvq::server {

Executor make_pipeline_executor() {
  return [](const JobSpec&, const std::string&, const std::string&, JobContext&) {
    throw Error("unavailable", "this build of btfvq-server has no compressor linked in");
  };
}

void validate_pipeline_overrides(const nlohmann::json& overrides) {
  if (!overrides.is_object()) throw InputError("pipeline: must be an object", "invalid_request");
}

std::vector<std::string> synthetic_presets() {
  // DESIGN.md section 6; replaced by the generator's own list.
  return {"bumps", "weave", "grain", "flakes", "fibres", "tile", "foil", "wool", "corduroy"};
}

}  // namespace btfvq::server
