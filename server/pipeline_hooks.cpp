// Submit-time checks that need the pipeline: the synthetic presets that exist, and the check of a
// job's pipeline overrides against configs/pipeline.json: every key must exist in the defaults with
// the same JSON type, and the merged settings must pass the pipeline's own validation (ranges,
// NaN), so that a typo or an out-of-range threshold is a 400 now rather than a failed job later.
#include "pipeline/encode/compress.h"
#include "pipeline/util/config.h"
#include <btfvq/error.h>
#include "pipeline/io/synthetic.h"
#include "server/executor.h"

namespace btfvq::server {
namespace {

std::string type_name(const nlohmann::json& v) {
  if (v.is_number_integer()) return "an integer";
  if (v.is_number()) return "a number";
  if (v.is_boolean()) return "true or false";
  if (v.is_string()) return "a string";
  if (v.is_array()) return "an array";
  if (v.is_object()) return "an object";
  return "null";
}

void check_against(const nlohmann::json& defaults, const nlohmann::json& overrides, const std::string& prefix) {
  for (const auto& [key, value] : overrides.items()) {
    const std::string where = prefix + "." + key;
    if (!defaults.contains(key)) throw ConfigError(where + ": unknown key (not in configs/pipeline.json)");
    const auto& d = defaults[key];
    const bool same_kind = (d.is_number() && value.is_number()) || (d.is_string() && value.is_string()) ||
                           (d.is_boolean() && value.is_boolean()) || (d.is_array() && value.is_array()) ||
                           (d.is_object() && value.is_object());
    if (!same_kind || (d.is_number_integer() && !value.is_number_integer()))
      throw ConfigError(where + ": must be " + type_name(d) + " (got " + value.dump() + ")");
    if (d.is_object()) check_against(d, value, where);
  }
}

}  // namespace

void validate_pipeline_overrides(const nlohmann::json& overrides) {
  if (!overrides.is_object()) throw InputError("pipeline: must be an object", "invalid_request");
  auto config = ParameterDictionary::embedded_default("pipeline");
  check_against(config.json(), overrides, "pipeline");
  config.merge(ParameterDictionary(overrides, "pipeline"));
  validate_pipeline_config(config);
}

std::vector<std::string> synthetic_presets() {
  std::vector<std::string> names;
  for (const auto& p : btfvq::synthetic_presets()) names.push_back(p.name);
  return names;
}

}  // namespace btfvq::server
