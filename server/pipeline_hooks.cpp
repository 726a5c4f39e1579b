// Submit-time checks that need the pipeline: the synthetic presets that exist, and a job's pipeline
// overrides checked by the same pipeline_config() the executor and `btfvq compress --config` use,
// so that a typo or an out-of-range threshold is a 400 now rather than a failed job later.
#include "pipeline/encode/compress.h"
#include <btfvq/error.h>
#include "pipeline/io/synthetic.h"
#include "server/executor.h"

namespace btfvq::server {

void validate_pipeline_overrides(const nlohmann::json& overrides) {
  if (!overrides.is_object()) throw InputError("pipeline: must be an object", "invalid_request");
  pipeline_config(overrides, "pipeline");
}

std::vector<std::string> synthetic_presets() {
  std::vector<std::string> names;
  for (const auto& p : btfvq::synthetic_presets()) names.push_back(p.name);
  return names;
}

}  // namespace btfvq::server
