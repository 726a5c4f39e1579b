#include "server/job_request.h"

#include <algorithm>
#include <iterator>
#include <regex>
#include <set>

#include "pipeline/encode/quality.h"
#include "pipeline/encode/target.h"
#include "pipeline/metrics/btf_cielab.h"
#include "pipeline/io/sample_io.h"
#include <btfvq/error.h>
#include "server/errors.h"

namespace btfvq::server {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr size_t kMaxMaterialsPerJob = 256;
constexpr int kMinSyntheticSize = 4, kMaxSyntheticSize = 2048;  // the generator accepts up to 2048
constexpr int64_t kMaxSeed = (int64_t(1) << 53);

// A default name comes from an upload id, a file stem or a preset: made valid rather than refused.
std::string sanitized_name(std::string s) {
  for (char& c : s)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '.' && c != '_' && c != '-') c = '_';
  if (s.empty() || !std::isalnum(static_cast<unsigned char>(s[0]))) s = "m" + s;
  return s.substr(0, 64);
}

// Every rejection names the field, as a path from the top of the request.
InputError invalid(const std::string& field, const std::string& why) {
  return InputError(field + ": " + why, "invalid_request");
}

std::string field_of(const std::string& where, const std::string& key) {
  return where.empty() ? key : where + "." + key;
}

void only_keys(const json& obj, const std::string& where, std::initializer_list<const char*> allowed) {
  for (const auto& [key, value] : obj.items())
    if (std::none_of(allowed.begin(), allowed.end(), [&](const char* a) { return key == a; }))
      throw invalid(field_of(where, key), "unknown field");
}

const json& require_object(const json& v, const std::string& where) {
  if (!v.is_object()) throw invalid(where, "must be an object");
  return v;
}

std::string require_string(const json& obj, const std::string& key, const std::string& where) {
  const std::string field = field_of(where, key);
  if (!obj.contains(key)) throw invalid(field, "missing");
  if (!obj[key].is_string()) throw invalid(field, "must be a string");
  return obj[key].get<std::string>();
}

int64_t require_integer(const json& obj, const std::string& key, const std::string& where, int64_t lo, int64_t hi) {
  const std::string field = where + "." + key;
  const std::string range = "[" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
  if (!obj.contains(key)) throw invalid(field, "missing");
  const json& v = obj[key];
  if (!v.is_number_integer()) throw invalid(field, "must be an integer in " + range);
  if (v.is_number_unsigned() && v.get<uint64_t>() > uint64_t(hi))
    throw invalid(field, v.dump() + " is out of range " + range);
  const int64_t n = v.get<int64_t>();
  if (n < lo || n > hi) throw invalid(field, std::to_string(n) + " is out of range " + range);
  return n;
}

const json& require_materials(const json& request) {
  if (!request.contains("materials")) throw invalid("materials", "missing");
  const json& materials = request["materials"];
  if (!materials.is_array() || materials.empty() || materials.size() > kMaxMaterialsPerJob)
    throw invalid("materials", "must be an array of 1.." + std::to_string(kMaxMaterialsPerJob) + " materials");
  return materials;
}

// The job's settings: its "pipeline" overrides, on top of what its "quality" stands for if given
// (the same rule as `btfvq compress --quality`).
json pipeline_overrides(const json& request) {
  json pipeline = request.value("pipeline", json::object());
  if (!pipeline.is_object()) throw invalid("pipeline", "must be an object");
  // One way to choose the settings' level: a quality, or a target to search it for.
  const std::string knobs[] = {"quality", "target_mssim", "target_btf_cielab"};
  for (size_t i = 0; i < std::size(knobs); ++i)
    for (size_t k = i + 1; k < std::size(knobs); ++k)
      if (request.contains(knobs[i]) && request.contains(knobs[k]))
        throw invalid(knobs[i], "and \"" + knobs[k] + "\" exclude each other");
  if (request.contains("target_mssim")) {
    const json& t = request["target_mssim"];
    if (!t.is_number() || !(t.get<double>() >= 0.01 && t.get<double>() <= 0.999))
      throw invalid("target_mssim", "must be a number from 0.01 to 0.999");
  }
  if (request.contains("target_btf_cielab")) {
    const json& t = request["target_btf_cielab"];
    if (!t.is_number() || !(t.get<double>() >= kMinTargetBtfCielab && t.get<double>() <= kMaxTargetBtfCielab))
      throw invalid("target_btf_cielab", "must be a number from " + json(kMinTargetBtfCielab).dump() + " to " +
                                             json(kMaxTargetBtfCielab).dump());
  }
  if (request.contains("quality")) {
    const json& q = request["quality"];
    if (!q.is_number() || !(q.get<double>() >= 0 && q.get<double>() <= 100)) throw invalid("quality", "must be a number from 0 to 100");
    pipeline = with_quality(q.get<double>(), pipeline);
  }
  validate_pipeline_overrides(pipeline);
  return pipeline;
}

// "btf_cielab": "default" or "RESOLUTION,SPEED", read by the parser of `btfvq eval --metric
// btf-cielab:RESOLUTION,SPEED`. Checked at submit time, read again from the stored request.
ViewingCondition btf_cielab_condition(const json& v) {
  if (!v.is_string()) throw invalid("btf_cielab", "must be \"default\" or \"RESOLUTION,SPEED\" (a string)");
  const std::string text = v.get<std::string>();
  if (text == "default") return {};
  try {
    return parse_viewing_condition(text);
  } catch (const InputError& e) {
    throw invalid("btf_cielab", std::string(e.what()) + " (expected \"default\" or \"RESOLUTION,SPEED\")");
  }
}

}  // namespace

bool valid_name(const std::string& s) {
  static const std::regex re("[A-Za-z0-9][A-Za-z0-9._-]{0,63}");
  return std::regex_match(s, re);
}

JobRequests::JobRequests(Store& store, DataDir data, fs::path input_root, uint64_t max_expanded_bytes)
    : store_(store),
      data_(std::move(data)),
      input_root_(std::move(input_root)),
      max_expanded_bytes_(max_expanded_bytes) {}

json JobRequests::validate(const json& request, const std::string& id) const {
  require_object(request, "request body");
  only_keys(request, "", {"database", "materials", "pipeline", "quality", "target_mssim", "target_btf_cielab", "btf_cielab"});
  const std::string database = require_string(request, "database", "");
  if (!valid_name(database))
    throw invalid("database", "'" + database + "' is not a valid name (1-64 of [A-Za-z0-9._-], starting alphanumeric)");
  const json& materials = require_materials(request);

  std::set<std::string> existing;
  if (auto versions = store_.versions(database); !versions.empty())
    for (const auto& m : versions.back().materials) existing.insert(m.value("name", ""));
  json normalized = json::array();
  std::set<std::string> names;
  for (size_t i = 0; i < materials.size(); ++i) {
    const std::string where = "materials[" + std::to_string(i) + "]";
    json m = material(materials[i], where);
    const std::string name = m["name"];
    if (!names.insert(name).second) throw invalid(where + ".name", "'" + name + "' appears twice in this job");
    if (existing.count(name))
      throw invalid(where + ".name", "database '" + database + "' already has a material '" + name + "'");
    normalized.push_back(std::move(m));
  }
  json out = {{"id", id}, {"database", database}, {"materials", normalized}, {"pipeline", pipeline_overrides(request)}};
  if (request.contains("quality")) out["quality"] = request["quality"];
  for (const char* key : {"target_mssim", "target_btf_cielab"})
    if (request.contains(key)) out[key] = request[key];
  if (request.contains("btf_cielab")) {
    btf_cielab_condition(request["btf_cielab"]);
    out["btf_cielab"] = request["btf_cielab"];
  }
  return out;
}

json JobRequests::material(const json& m, const std::string& where) const {
  require_object(m, where);
  only_keys(m, where, {"name", "source"});
  const std::string src = where + ".source";
  if (!m.contains("source")) throw invalid(src, "missing");
  const json& source = require_object(m["source"], src);
  if (source.size() != 1) throw invalid(src, "must have exactly one of 'upload', 'path', 'synthetic'");
  only_keys(source, src, {"upload", "path", "synthetic"});
  const Source s = source.contains("upload") ? upload_source(source, src)
                   : source.contains("path") ? path_source(source, src)
                                             : synthetic_source(source, src);
  const std::string name = m.contains("name") ? require_string(m, "name", where) : sanitized_name(s.default_name);
  if (!valid_name(name)) throw invalid(where + ".name", "'" + name + "' is not a valid name (1-64 of [A-Za-z0-9._-])");
  return {{"name", name}, {"source", s.normalized}};
}

JobRequests::Source JobRequests::upload_source(const json& source, const std::string& where) const {
  const std::string upload = require_string(source, "upload", where);
  auto record = store_.upload(upload);
  if (!record || record->state != "complete") throw invalid(where + ".upload", "no completed upload '" + upload + "'");
  check_sample(data_.upload(upload), where + ".upload");
  return {{{"upload", upload}}, upload};
}

JobRequests::Source JobRequests::path_source(const json& source, const std::string& where) const {
  const fs::path real = resolve_input_path(require_string(source, "path", where), where + ".path");
  check_sample(real, where + ".path");
  return {{{"path", real.string()}}, real.stem().string()};
}

JobRequests::Source JobRequests::synthetic_source(const json& source, const std::string& where) const {
  const std::string at = where + ".synthetic";
  const json& syn = require_object(source["synthetic"], at);
  only_keys(syn, at, {"preset", "size", "seed"});
  const std::string preset = require_string(syn, "preset", at);
  const auto presets = synthetic_presets();
  if (std::find(presets.begin(), presets.end(), preset) == presets.end()) {
    std::string known;
    for (const auto& p : presets) known += (known.empty() ? "" : ", ") + p;
    throw invalid(at + ".preset", "unknown preset '" + preset + "' (known: " + known + ")");
  }
  const int64_t size = require_integer(syn, "size", at, kMinSyntheticSize, kMaxSyntheticSize);
  const int64_t seed = syn.contains("seed") ? require_integer(syn, "seed", at, 0, kMaxSeed) : 0;
  return {{{"synthetic", {{"preset", preset}, {"size", size}, {"seed", seed}}}}, preset + "-" + std::to_string(seed)};
}

// Names, archive entries that escape, the expanded size of an archive and one image header are
// cheap to check before the job exists.
void JobRequests::check_sample(const fs::path& file, const std::string& field) const {
  try {
    inspect_sample(file.string(), max_expanded_bytes_);
  } catch (const InputError& e) {
    throw InputError(field + ": " + e.what(), "invalid_sample");
  }
}

fs::path JobRequests::resolve_input_path(const std::string& given, const std::string& field) const {
  if (input_root_.empty()) throw ForbiddenError(field + ": server-side paths are disabled (no input_root is configured)");
  if (given.empty()) throw invalid(field, "must not be empty");
  const fs::path& root = input_root_;
  const fs::path candidate = (fs::path(given).is_absolute() ? fs::path(given) : root / given).lexically_normal();
  auto inside = [&](const fs::path& p) {
    const fs::path rel = p.lexically_relative(root);
    return !rel.empty() && *rel.begin() != "..";
  };
  if (!inside(candidate)) throw ForbiddenError(field + ": '" + given + "' is outside the input root");
  std::error_code ec;
  const fs::path real = fs::canonical(candidate, ec);
  if (ec) throw invalid(field, "'" + given + "' does not exist under the input root");
  // A symlink inside the root may point anywhere: judge the resolved path.
  if (!inside(real)) throw ForbiddenError(field + ": '" + given + "' resolves outside the input root");
  return real;
}

JobSpec JobRequests::spec(const JobRecord& job) const {
  JobSpec spec;
  spec.id = job.id;
  spec.database = job.database;
  spec.pipeline = job.spec.value("pipeline", json::object());
  spec.target_mssim = job.spec.value("target_mssim", 0.0);
  spec.target_btf_cielab = job.spec.value("target_btf_cielab", 0.0);
  if (job.spec.contains("btf_cielab")) spec.btf_cielab = btf_cielab_condition(job.spec["btf_cielab"]);
  for (const auto& m : job.spec["materials"]) {
    MaterialSpec ms;
    ms.name = m["name"];
    const json& s = m["source"];
    if (s.contains("upload")) {
      ms.kind = "upload";
      ms.upload_id = s["upload"];
      ms.file = data_.upload(ms.upload_id).string();
    } else if (s.contains("path")) {
      ms.kind = "path";
      ms.file = s["path"];
    } else {
      ms.kind = "synthetic";
      ms.preset = s["synthetic"]["preset"];
      ms.size = s["synthetic"]["size"];
      ms.seed = s["synthetic"]["seed"];
    }
    spec.materials.push_back(ms);
  }
  return spec;
}

}  // namespace btfvq::server
