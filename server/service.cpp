#include "server/service.h"

#include "pipeline/io/sample_io.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <regex>
#include <sstream>

#include <btfvq/error.h>
#include "server/errors.h"

namespace btfvq::server {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr size_t kMaxMaterialsPerJob = 256;
constexpr int kMinSyntheticSize = 4, kMaxSyntheticSize = 2048;  // the generator accepts up to 2048
constexpr int64_t kMaxSeed = (int64_t(1) << 53);

double now_seconds() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

std::string random_hex(size_t n) {
  static thread_local std::mt19937_64 rng{std::random_device{}()};
  static const char* digits = "0123456789abcdef";
  std::string s;
  for (size_t i = 0; i < n; ++i) s += digits[rng() & 15];
  return s;
}

// Names of databases, materials and uploads end up in file names and URLs: keep them boring.
bool valid_name(const std::string& s) {
  static const std::regex re("[A-Za-z0-9][A-Za-z0-9._-]{0,63}");
  return std::regex_match(s, re);
}

std::string sanitized_name(std::string s) {
  for (char& c : s)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '.' && c != '_' && c != '-') c = '_';
  if (s.empty() || !std::isalnum(static_cast<unsigned char>(s[0]))) s = "m" + s;
  return s.substr(0, 64);
}

// ---- request validation: every rejection names the field ----

void only_keys(const json& obj, const std::string& where, std::initializer_list<const char*> allowed) {
  for (const auto& [key, value] : obj.items()) {
    if (std::none_of(allowed.begin(), allowed.end(), [&](const char* a) { return key == a; }))
      throw InputError(where + (where.empty() ? "" : ".") + key + ": unknown field", "invalid_request");
  }
}

const json& require_object(const json& v, const std::string& where) {
  if (!v.is_object()) throw InputError(where + ": must be an object", "invalid_request");
  return v;
}

std::string require_string(const json& obj, const std::string& key, const std::string& where) {
  const std::string field = where.empty() ? key : where + "." + key;
  if (!obj.contains(key)) throw InputError(field + ": missing", "invalid_request");
  if (!obj[key].is_string()) throw InputError(field + ": must be a string", "invalid_request");
  return obj[key].get<std::string>();
}

int64_t require_integer(const json& obj, const std::string& key, const std::string& where, int64_t lo, int64_t hi) {
  const std::string field = where + "." + key;
  if (!obj.contains(key)) throw InputError(field + ": missing", "invalid_request");
  const json& v = obj[key];
  if (!v.is_number_integer())
    throw InputError(field + ": must be an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]",
                     "invalid_request");
  if (v.is_number_unsigned() && v.get<uint64_t>() > uint64_t(hi))
    throw InputError(field + ": " + v.dump() + " is out of range [" + std::to_string(lo) + ", " + std::to_string(hi) + "]",
                     "invalid_request");
  const int64_t n = v.get<int64_t>();
  if (n < lo || n > hi)
    throw InputError(field + ": " + std::to_string(n) + " is out of range [" + std::to_string(lo) + ", " +
                         std::to_string(hi) + "]",
                     "invalid_request");
  return n;
}


json version_json(const VersionRecord& v) {
  uint64_t raw = 0;
  for (const auto& m : v.materials) raw += m.value("raw_bytes", uint64_t(0));
  return {{"version", v.version},
          {"size", v.size},
          {"sha256", v.sha256},
          {"created", v.created},
          {"job", v.job},
          {"materials", v.materials},
          {"raw_bytes", raw},
          {"ratio", v.size > 0 ? double(raw) / double(v.size) : 0.0}};
}

}  // namespace

// ---------------------------------------------------------------- uploads

UploadSink::UploadSink(Service& service, std::string id)
    : service_(service), id_(std::move(id)), file_(service_.upload_path(id_).string()) {
  out_.open(file_.temp_path(), std::ios::binary | std::ios::trunc);
  if (!out_) throw Error("io", "cannot create '" + file_.temp_path() + "'");
}

UploadSink::~UploadSink() {
  if (out_.is_open()) out_.close();
  if (!done_ && size_ > 0) spdlog::info("upload {} abandoned after {} bytes", id_, size_);
  std::lock_guard lock(service_.mutex_);
  service_.uploading_.erase(id_);
}

bool UploadSink::write(const char* data, size_t size) {
  if (size_ + size > service_.config_.max_upload_bytes) {
    too_large_ = true;
    return false;
  }
  out_.write(data, std::streamsize(size));
  hash_.update(data, size);
  size_ += size;
  *progress_ = size_;
  service_.bytes_uploaded_ += size;
  return bool(out_);
}

json UploadSink::finish(const std::string& expected_sha256) {
  out_.close();
  if (!out_) throw Error("io", "cannot write upload '" + id_ + "'");
  const std::string sha = hash_.hex();
  if (!expected_sha256.empty() && expected_sha256 != sha)
    throw InputError("X-Sha256: the upload hashes to " + sha + ", not " + expected_sha256, "checksum_mismatch");
  file_.commit();
  UploadRecord record{id_, size_, sha, "complete", now_seconds()};
  service_.store_->insert_upload(record);
  done_ = true;
  spdlog::info("upload {} complete: {} bytes, sha256 {}", id_, size_, sha);
  return {{"id", id_}, {"size", size_}, {"sha256", sha}, {"state", "complete"}};
}

std::unique_ptr<UploadSink> Service::begin_upload(const std::string& id, std::optional<uint64_t> declared_size) {
  if (!valid_name(id)) throw InputError("upload id '" + id + "': use 1-64 of [A-Za-z0-9._-]", "invalid_request");
  if (declared_size && *declared_size > config_.max_upload_bytes)
    throw TooLargeError("upload of " + std::to_string(*declared_size) + " bytes exceeds the limit of " +
                        std::to_string(config_.max_upload_bytes) + " bytes");
  {
    std::lock_guard lock(mutex_);
    if (uploading_.count(id)) throw ConflictError("upload '" + id + "' is in progress");
    if (store_->upload(id)) throw ConflictError("upload '" + id + "' exists already");
    uploading_[id] = std::make_shared<std::atomic<uint64_t>>(0);
  }
  try {
    std::unique_ptr<UploadSink> sink(new UploadSink(*this, id));
    std::lock_guard lock(mutex_);
    sink->progress_ = uploading_[id];
    return sink;
  } catch (...) {
    std::lock_guard lock(mutex_);
    uploading_.erase(id);
    throw;
  }
}

json Service::upload(const std::string& id) {
  if (auto u = store_->upload(id))
    return {{"id", u->id}, {"size", u->size}, {"sha256", u->sha256}, {"state", u->state}, {"created", u->created}};
  std::lock_guard lock(mutex_);
  if (auto it = uploading_.find(id); it != uploading_.end())
    return {{"id", id}, {"size", it->second->load()}, {"state", "uploading"}};
  throw NotFoundError("no upload '" + id + "'");
}

fs::path Service::upload_path(const std::string& id) const { return config_.data_dir / "uploads" / (id + ".upload"); }

// ---------------------------------------------------------------- lifecycle

Service::Service(ServiceConfig config, Executor executor) : config_(std::move(config)), executor_(std::move(executor)) {
  if (config_.workers < 1) throw ConfigError("workers must be at least 1");
  fs::create_directories(config_.data_dir / "uploads");
  fs::create_directories(config_.data_dir / "databases");
  if (!config_.input_root.empty()) {
    std::error_code ec;
    config_.input_root = fs::canonical(config_.input_root, ec);
    if (ec) throw ConfigError("input_root '" + config_.input_root.string() + "' does not exist");
  }
  store_ = std::make_unique<Store>((config_.data_dir / "btfvq.sqlite").string());
}

Service::~Service() { stop(); }

void Service::start() {
  if (started_) return;
  recover();
  started_ = true;
  for (int i = 0; i < config_.workers; ++i) workers_.emplace_back([this] { worker_loop(); });
  spdlog::info("service started: data {}, {} worker(s)", config_.data_dir.string(), config_.workers);
}

void Service::stop() {
  {
    std::lock_guard lock(mutex_);
    if (stopping_ && workers_.empty()) return;
    stopping_ = true;
    notify();
  }
  work_cv_.notify_all();
  for (auto& t : workers_) t.join();
  workers_.clear();
}

void Service::recover() {
  for (const auto& id : store_->requeue_running()) spdlog::warn("job {} was running when the server stopped: re-queued", id);
  // Anything in the data directory that the store does not list is a leftover of a crash.
  std::set<std::string> listed;
  for (const auto& p : store_->all_version_paths()) listed.insert((config_.data_dir / p).lexically_normal().string());
  for (const auto& entry : fs::recursive_directory_iterator(config_.data_dir / "databases")) {
    if (!entry.is_regular_file()) continue;
    if (!listed.count(entry.path().lexically_normal().string())) {
      spdlog::warn("removing unlisted file {}", entry.path().string());
      fs::remove(entry.path());
    }
  }
  for (const auto& entry : fs::directory_iterator(config_.data_dir / "uploads")) {
    const std::string name = entry.path().filename().string();
    const bool complete = entry.path().extension() == ".upload" &&
                          store_->upload(entry.path().stem().string()).has_value();
    if (!complete) {
      spdlog::warn("removing interrupted upload {}", entry.path().string());
      fs::remove_all(entry.path());
    }
  }
}

void Service::notify() {
  ++revision_;
  change_cv_.notify_all();
}

uint64_t Service::revision() {
  std::lock_guard lock(mutex_);
  return revision_;
}

uint64_t Service::wait_for_change(uint64_t revision, std::chrono::milliseconds timeout) {
  std::unique_lock lock(mutex_);
  change_cv_.wait_for(lock, timeout, [&] { return revision_ != revision || stopping_; });
  return revision_;
}

// ---------------------------------------------------------------- submission

// A sample is checked when the job is submitted (names, escaping archive entries, the expanded size
// of an archive, one image header), so that such input is a 400 and no job is created.
void Service::check_sample(const fs::path& file, const std::string& field) const {
  try {
    inspect_sample(file.string(), config_.max_expanded_bytes);
  } catch (const InputError& e) {
    throw InputError(field + ": " + e.what(), "invalid_sample");
  }
}

fs::path Service::resolve_input_path(const std::string& given, const std::string& field) const {
  if (config_.input_root.empty())
    throw ForbiddenError(field + ": server-side paths are disabled (no input_root is configured)");
  if (given.empty()) throw InputError(field + ": must not be empty", "invalid_request");
  const fs::path root = config_.input_root;
  const fs::path candidate = (fs::path(given).is_absolute() ? fs::path(given) : root / given).lexically_normal();
  auto inside = [&](const fs::path& p) {
    const fs::path rel = p.lexically_relative(root);
    return !rel.empty() && *rel.begin() != "..";
  };
  if (!inside(candidate)) throw ForbiddenError(field + ": '" + given + "' is outside the input root");
  std::error_code ec;
  const fs::path real = fs::canonical(candidate, ec);
  if (ec) throw InputError(field + ": '" + given + "' does not exist under the input root", "invalid_request");
  // A symlink inside the root may point anywhere: judge the resolved path.
  if (!inside(real)) throw ForbiddenError(field + ": '" + given + "' resolves outside the input root");
  return real;
}

json Service::validate_request(const json& request, const std::string& id) {
  require_object(request, "request body");
  only_keys(request, "", {"database", "materials", "pipeline"});
  const std::string database = require_string(request, "database", "");
  if (!valid_name(database))
    throw InputError("database: '" + database + "' is not a valid name (1-64 of [A-Za-z0-9._-], starting alphanumeric)",
                     "invalid_request");
  if (!request.contains("materials")) throw InputError("materials: missing", "invalid_request");
  const json& materials = request["materials"];
  if (!materials.is_array() || materials.empty() || materials.size() > kMaxMaterialsPerJob)
    throw InputError("materials: must be an array of 1.." + std::to_string(kMaxMaterialsPerJob) + " materials",
                     "invalid_request");

  std::set<std::string> existing;
  if (auto versions = store_->versions(database); !versions.empty())
    for (const auto& m : versions.back().materials) existing.insert(m.value("name", ""));
  const auto presets = synthetic_presets();

  json normalized = json::array();
  std::set<std::string> names;
  for (size_t i = 0; i < materials.size(); ++i) {
    const std::string where = "materials[" + std::to_string(i) + "]";
    const json& m = require_object(materials[i], where);
    only_keys(m, where, {"name", "source"});
    if (!m.contains("source")) throw InputError(where + ".source: missing", "invalid_request");
    const json& source = require_object(m["source"], where + ".source");
    if (source.size() != 1)
      throw InputError(where + ".source: must have exactly one of 'upload', 'path', 'synthetic'", "invalid_request");
    only_keys(source, where + ".source", {"upload", "path", "synthetic"});
    json out = json::object();
    std::string default_name;
    const std::string src = where + ".source";
    if (source.contains("upload")) {
      const std::string upload = require_string(source, "upload", src);
      auto record = store_->upload(upload);
      if (!record || record->state != "complete")
        throw InputError(src + ".upload: no completed upload '" + upload + "'", "invalid_request");
      out["source"] = {{"upload", upload}};
      default_name = upload;
      check_sample(upload_path(upload), src + ".upload");
    } else if (source.contains("path")) {
      const std::string given = require_string(source, "path", src);
      const fs::path real = resolve_input_path(given, src + ".path");
      out["source"] = {{"path", real.string()}};
      default_name = real.stem().string();
      check_sample(real, src + ".path");
    } else {
      const json& syn = require_object(source["synthetic"], src + ".synthetic");
      only_keys(syn, src + ".synthetic", {"preset", "size", "seed"});
      const std::string preset = require_string(syn, "preset", src + ".synthetic");
      if (std::find(presets.begin(), presets.end(), preset) == presets.end()) {
        std::string known;
        for (const auto& p : presets) known += (known.empty() ? "" : ", ") + p;
        throw InputError(src + ".synthetic.preset: unknown preset '" + preset + "' (known: " + known + ")",
                         "invalid_request");
      }
      const int64_t size = require_integer(syn, "size", src + ".synthetic", kMinSyntheticSize, kMaxSyntheticSize);
      const int64_t seed = syn.contains("seed") ? require_integer(syn, "seed", src + ".synthetic", 0, kMaxSeed) : 0;
      out["source"] = {{"synthetic", {{"preset", preset}, {"size", size}, {"seed", seed}}}};
      default_name = preset + "-" + std::to_string(seed);
    }
    std::string name = m.contains("name") ? require_string(m, "name", where) : sanitized_name(default_name);
    if (!valid_name(name))
      throw InputError(where + ".name: '" + name + "' is not a valid name (1-64 of [A-Za-z0-9._-])", "invalid_request");
    if (!names.insert(name).second)
      throw InputError(where + ".name: '" + name + "' appears twice in this job", "invalid_request");
    if (existing.count(name))
      throw InputError(where + ".name: database '" + database + "' already has a material '" + name + "'",
                       "invalid_request");
    out["name"] = name;
    normalized.push_back(out);
  }
  json pipeline = json::object();
  if (request.contains("pipeline")) {
    pipeline = request["pipeline"];
    if (!pipeline.is_object()) throw InputError("pipeline: must be an object", "invalid_request");
    validate_pipeline_overrides(pipeline);
  }
  return {{"id", id}, {"database", database}, {"materials", normalized}, {"pipeline", pipeline}};
}

json Service::submit(const json& request) {
  const std::string id = "j" + random_hex(15);
  JobRecord job;
  job.id = id;
  job.spec = validate_request(request, id);
  job.database = job.spec["database"];
  job.created = now_seconds();
  {
    std::lock_guard lock(mutex_);
    if (stopping_) throw Error("unavailable", "the server is shutting down");
    job.seq = store_->insert_job(job);
    notify();
  }
  work_cv_.notify_all();
  spdlog::info("job {} queued for database {} ({} material(s))", id, job.database, job.spec["materials"].size());
  return this->job(id);
}

JobSpec Service::parse_spec(const JobRecord& job) const {
  JobSpec spec;
  spec.id = job.id;
  spec.database = job.database;
  spec.pipeline = job.spec.value("pipeline", json::object());
  for (const auto& m : job.spec["materials"]) {
    MaterialSpec ms;
    ms.name = m["name"];
    const json& s = m["source"];
    if (s.contains("upload")) {
      ms.kind = "upload";
      ms.upload_id = s["upload"];
      ms.file = upload_path(ms.upload_id).string();
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

// ---------------------------------------------------------------- job views

json Service::job_json(const JobRecord& job) {
  json progress = job.progress.is_object() ? job.progress : json::object();
  if (auto it = live_.find(job.id); it != live_.end()) progress = it->second.progress;
  const double now = now_seconds();
  const double end = job.finished > 0 ? job.finished : now;
  const double elapsed = job.started > 0 ? std::max(0.0, end - job.started) : 0.0;
  const double fraction = progress.value("fraction", job.state == JobState::succeeded ? 1.0 : 0.0);
  json eta = nullptr;
  if (job.state == JobState::running && fraction > 0.001) eta = elapsed * (1 - fraction) / fraction;
  json materials = json::array();
  for (const auto& m : job.spec["materials"]) materials.push_back(m["name"]);
  return {{"id", job.id},
          {"database", job.database},
          {"state", job.state},
          {"stage", progress.value("stage", "")},
          {"phase", progress.value("phase", 0)},
          {"fraction", fraction},
          {"material", progress.value("material", "")},
          {"texels_done", progress.value("texels_done", uint64_t(0))},
          {"texels_total", progress.value("texels_total", uint64_t(0))},
          {"codebook_sizes", progress.value("codebook_sizes", json(CodebookSizes{}))},
          {"created", job.created},
          {"started", job.started > 0 ? json(job.started) : json()},
          {"finished", job.finished > 0 ? json(job.finished) : json()},
          {"elapsed_s", elapsed},
          {"eta_s", eta},
          {"error", job.error},
          {"version", job.version > 0 ? json(job.version) : json()},
          {"materials", materials},
          {"request", job.spec}};
}

// Store reads happen under mutex_ so that a record and the live progress are one snapshot.
json Service::job(const std::string& id) {
  std::lock_guard lock(mutex_);
  auto record = store_->job(id);
  if (!record) throw NotFoundError("no job '" + id + "'");
  return job_json(*record);
}

json Service::jobs() {
  std::lock_guard lock(mutex_);
  auto records = store_->jobs();
  json out = json::array();
  for (const auto& r : records) {
    json j = job_json(r);
    j.erase("request");
    out.push_back(j);
  }
  return out;
}

json Service::cancel(const std::string& id) {
  {
    std::lock_guard lock(mutex_);
    auto record = store_->job(id);
    if (!record) throw NotFoundError("no job '" + id + "'");
    if (is_final(record->state)) throw ConflictError("job '" + id + "' is already " + to_string(record->state));
    if (record->state == JobState::queued) {
      store_->set_job_state(id, JobState::cancelled, json{{"code", "cancelled"}, {"message", "cancelled while queued"}}, 0,
                            now_seconds());
    } else if (auto it = live_.find(id); it != live_.end()) {
      it->second.cancel_requested = true;  // the executor notices at its next poll
    }
    notify();
  }
  spdlog::info("job {}: cancel requested", id);
  return job(id);
}

// ---------------------------------------------------------------- catalogue

json Service::databases() {
  json out = json::array();
  for (const auto& name : store_->database_names()) {
    const auto versions = store_->versions(name);
    json newest = version_json(versions.back());
    out.push_back({{"name", name},
                   {"versions", versions.size()},
                   {"version", newest["version"]},
                   {"size", newest["size"]},
                   {"sha256", newest["sha256"]},
                   {"materials", newest["materials"].size()},
                   {"raw_bytes", newest["raw_bytes"]},
                   {"ratio", newest["ratio"]},
                   {"updated", newest["created"]}});
  }
  return out;
}

json Service::database(const std::string& name) {
  const auto versions = store_->versions(name);
  if (versions.empty()) throw NotFoundError("no database '" + name + "'");
  json all = json::array();
  for (const auto& v : versions) all.push_back(version_json(v));
  return {{"name", name}, {"newest", all.back()}, {"versions", all}};
}

ContentInfo Service::content(const std::string& name, std::optional<int64_t> version) {
  const auto versions = store_->versions(name);
  if (versions.empty()) throw NotFoundError("no database '" + name + "'");
  const VersionRecord* v = &versions.back();
  if (version) {
    auto it = std::find_if(versions.begin(), versions.end(), [&](const auto& r) { return r.version == *version; });
    if (it == versions.end())
      throw NotFoundError("database '" + name + "' has no version " + std::to_string(*version));
    v = &*it;
  }
  return {name, v->version, config_.data_dir / v->path, v->size, v->sha256};
}

std::vector<uint8_t> Service::preview(const std::string& database, const std::string& material,
                                      const PreviewOptions& options) {
  const ContentInfo c = content(database, std::nullopt);
  std::shared_ptr<const BtfDatabase> db;
  {
    std::lock_guard lock(preview_mutex_);
    auto it = preview_cache_.find(c.path);
    if (it != preview_cache_.end()) db = it->second;
  }
  if (!db) {
    db = std::make_shared<const BtfDatabase>(BtfDatabase::open(c.path.string()));
    std::lock_guard lock(preview_mutex_);
    if (preview_cache_.size() >= 4) preview_cache_.clear();
    preview_cache_[c.path] = db;
  }
  const BtfMaterial m = db->material(material);
  return render_preview_png(db->decoder(), m.index(), options);
}

std::string Service::metrics() {
  std::map<std::string, int> by_state;  // by name: the labels come out sorted
  for (JobState s : kJobStates) by_state[to_string(s)] = 0;
  for (const auto& j : store_->jobs()) ++by_state[to_string(j.state)];
  std::ostringstream m;
  m << "# HELP btfvq_jobs Jobs by state.\n# TYPE btfvq_jobs gauge\n";
  for (const auto& [state, n] : by_state) m << "btfvq_jobs{state=\"" << state << "\"} " << n << "\n";
  m << "# HELP btfvq_queue_length Jobs waiting for a worker.\n# TYPE btfvq_queue_length gauge\n"
    << "btfvq_queue_length " << by_state[to_string(JobState::queued)] << "\n";
  m << "# HELP btfvq_workers Configured worker count.\n# TYPE btfvq_workers gauge\nbtfvq_workers " << config_.workers
    << "\n";
  m << "# HELP btfvq_bytes_served_total Database bytes sent to clients.\n# TYPE btfvq_bytes_served_total counter\n"
    << "btfvq_bytes_served_total " << bytes_served_.load() << "\n";
  m << "# HELP btfvq_bytes_uploaded_total Upload bytes received.\n# TYPE btfvq_bytes_uploaded_total counter\n"
    << "btfvq_bytes_uploaded_total " << bytes_uploaded_.load() << "\n";
  m << "# HELP btfvq_databases Databases in the catalogue.\n# TYPE btfvq_databases gauge\n"
    << "btfvq_databases " << store_->database_names().size() << "\n";
  std::lock_guard lock(mutex_);
  m << "# HELP btfvq_stage_seconds_total Time spent by jobs in each stage (phase1/2/3, ...).\n"
    << "# TYPE btfvq_stage_seconds_total counter\n";
  for (const auto& [stage, s] : stage_seconds_) m << "btfvq_stage_seconds_total{stage=\"" << stage << "\"} " << s << "\n";
  return m.str();
}

// ---------------------------------------------------------------- workers

std::optional<JobRecord> Service::next_job() {
  // Oldest queued job whose database is idle: FIFO per database, parallel across databases.
  for (auto& j : store_->jobs_in_state(JobState::queued))
    if (!busy_databases_.count(j.database)) return j;
  return std::nullopt;
}

void Service::worker_loop() {
  for (;;) {
    JobRecord job;
    {
      std::unique_lock lock(mutex_);
      std::optional<JobRecord> next;
      work_cv_.wait(lock, [&] { return stopping_ || (next = next_job()).has_value(); });
      if (stopping_) return;
      job = *next;
      busy_databases_.insert(job.database);
      job.started = now_seconds();
      job.state = JobState::running;
      Live live;
      live.stage_started = job.started;
      live_[job.id] = live;
      store_->set_job_state(job.id, JobState::running, nullptr, job.started, 0);
      notify();
    }
    run(job);
    {
      std::lock_guard lock(mutex_);
      busy_databases_.erase(job.database);
      if (auto it = live_.find(job.id); it != live_.end()) {
        finish_stage(it->second, now_seconds());
        live_.erase(it);
      }
      notify();
    }
    work_cv_.notify_all();
  }
}

void Service::finish_stage(Live& live, double now) {
  if (!live.stage.empty()) stage_seconds_[live.stage] += now - live.stage_started;
  live.stage_started = now;
}

void Service::on_progress(const std::string& id, const JobProgress& p) {
  std::lock_guard lock(mutex_);
  auto it = live_.find(id);
  if (it == live_.end()) return;
  Live& live = it->second;
  const double now = now_seconds();
  const bool stage_changed = p.stage != live.stage;
  if (stage_changed) {
    finish_stage(live, now);
    live.stage = p.stage;
  }
  live.progress = {{"stage", p.stage},
                   {"phase", p.phase},
                   {"fraction", std::isfinite(p.fraction) ? std::clamp(p.fraction, 0.0, 1.0) : 0.0},
                   {"texels_done", p.texels_done},
                   {"texels_total", p.texels_total},
                   {"codebook_sizes", p.codebook_sizes},
                   {"material", p.material}};
  // The store gets a copy now and then, so that a restarted server shows where a job was.
  if (stage_changed || now - live.last_persisted > 1.0) {
    store_->set_job_progress(id, live.progress);
    live.last_persisted = now;
  }
  notify();
}

void Service::run(const JobRecord& job) {
  const JobSpec spec = parse_spec(job);
  const auto versions = store_->versions(job.database);
  const std::string previous = versions.empty() ? std::string() : (config_.data_dir / versions.back().path).string();
  // The version this job will publish. No other job picks the same number meanwhile: worker_loop
  // runs one job per database at a time (busy_databases_), and the number moves on only when this
  // job publishes.
  VersionRecord next;
  next.database = job.database;
  next.version = versions.empty() ? 1 : versions.back().version + 1;
  next.path = (fs::path("databases") / job.database / ("v" + std::to_string(next.version) + ".btfdb")).string();
  next.materials = versions.empty() ? json::array() : versions.back().materials;
  const fs::path output = config_.data_dir / next.path;
  fs::create_directories(output.parent_path());

  JobContext ctx;
  ctx.progress = [this, id = job.id](const JobProgress& p) { on_progress(id, p); };
  ctx.cancelled = [this, id = job.id] {
    std::lock_guard lock(mutex_);
    auto it = live_.find(id);
    return stopping_ || (it != live_.end() && it->second.cancel_requested);
  };
  ctx.max_expanded_bytes = config_.max_expanded_bytes;
  if (!versions.empty())
    for (const auto& m : versions.back().materials) ctx.existing_materials.push_back(m.value("name", ""));

  spdlog::info("job {} running on database {}", job.id, job.database);
  // An executor that failed after writing (or a cancel that came after it) must not leave an
  // unlisted file where the version would be.
  auto remove_output = [&] {
    std::error_code ec;
    fs::remove(output, ec);
  };
  auto end_as = [&](JobState state, const json& error) {
    remove_output();
    std::lock_guard lock(mutex_);
    if (auto it = live_.find(job.id); it != live_.end()) store_->set_job_progress(job.id, it->second.progress);
    const bool requeued = state == JobState::queued;
    store_->set_job_state(job.id, state, error, requeued ? 0 : job.started, requeued ? 0 : now_seconds());
  };
  auto cancel_requested = [&] {
    std::lock_guard lock(mutex_);
    auto it = live_.find(job.id);
    return it != live_.end() && it->second.cancel_requested;
  };
  try {
    executor_(spec, previous, output.string(), ctx);
    if (cancel_requested()) throw CancelledError("cancelled by request");
    if (stopping_) throw CancelledError("server shutting down");
    if (!fs::is_regular_file(output)) throw Error("internal", "the executor did not write the database");
    publish(job, spec, std::move(next), ctx.added);
    spdlog::info("job {} succeeded", job.id);
  } catch (const CancelledError& e) {
    if (stopping_ && !cancel_requested()) {
      spdlog::warn("job {} interrupted by shutdown: re-queued", job.id);
      end_as(JobState::queued, nullptr);
    } else {
      spdlog::info("job {} cancelled", job.id);
      end_as(JobState::cancelled, {{"code", "cancelled"}, {"message", e.what()}});
    }
  } catch (const Error& e) {
    spdlog::warn("job {} failed: {}", job.id, e.what());
    end_as(JobState::failed, {{"code", e.code()}, {"message", e.what()}});
  } catch (const std::exception& e) {
    spdlog::error("job {} failed: {}", job.id, e.what());
    end_as(JobState::failed, {{"code", "internal"}, {"message", e.what()}});
  }
}

// The executor wrote the version's file atomically at its final path: publishing is hashing it and
// recording it.
void Service::publish(const JobRecord& job, const JobSpec& spec, VersionRecord v,
                      const std::vector<MaterialRecord>& added) {
  const fs::path file = config_.data_dir / v.path;
  v.sha256 = sha256_file(file.string());
  v.size = fs::file_size(file);
  std::vector<MaterialRecord> records = added;
  if (records.empty())  // an executor that reports nothing still added the job's materials
    for (const auto& m : spec.materials) records.push_back({m.name, 0, 0, 0, json::object()});
  for (const auto& m : records)
    v.materials.push_back({{"name", m.name},
                           {"raw_bytes", m.raw_bytes},
                           {"width", m.width},
                           {"height", m.height},
                           {"job", job.id},
                           {"version_added", v.version},
                           {"report", m.report}});
  v.job = job.id;
  v.created = now_seconds();
  std::lock_guard lock(mutex_);
  if (auto it = live_.find(job.id); it != live_.end()) {
    it->second.progress["fraction"] = 1.0;
    store_->set_job_progress(job.id, it->second.progress);
  }
  store_->publish(v, now_seconds());
}

}  // namespace btfvq::server
