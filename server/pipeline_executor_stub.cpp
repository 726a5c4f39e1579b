// Stand-in for the pipeline-backed executor until compress_material() links in this branch.
// The integrator deletes this file and renames pipeline_executor.cpp.pending to
// pipeline_executor.cpp (make_pipeline_executor() backed by compress_material()).
#include "pipeline/error.h"
#include "server/executor.h"

namespace btfvq::server {

Executor make_pipeline_executor() {
  return [](const JobSpec&, const std::string&, const std::string&, JobContext&) {
    throw Error("unavailable", "this build of btfvq-server has no compressor linked in");
  };
}

}  // namespace btfvq::server
