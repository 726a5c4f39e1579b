// Stand-ins for the pipeline-backed pieces of the server until the compressor library links in
// this branch. The integrator deletes this file and renames pipeline_executor.cpp.pending to
// pipeline_executor.cpp (the same two functions, backed by compress_material() and synthetic.h).
#include "pipeline/error.h"
#include "server/executor.h"

namespace btfvq::server {

Executor make_pipeline_executor() {
  return [](const JobSpec&, const std::string&, const std::string&, JobContext&) {
    throw Error("unavailable", "this build of btfvq-server has no compressor linked in");
  };
}

std::vector<std::string> synthetic_presets() {
  // The generator's presets on feat/synth (pipeline/synthetic.h); the pending file asks it directly.
  return {"tile", "foil", "wood", "leather", "fabric", "corduroy", "wool"};
}

}  // namespace btfvq::server
