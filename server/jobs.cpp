#include "server/jobs.h"

#ifdef __GLIBC__
#include <malloc.h>
#endif

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <random>

#include <btfvq/error.h>
#include "pipeline/encode/checkpoint.h"
#include "pipeline/util/atomic_file.h"
#include "server/errors.h"

namespace btfvq::server {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

std::string random_hex(size_t n) {
  static thread_local std::mt19937_64 rng{std::random_device{}()};
  static const char* digits = "0123456789abcdef";
  std::string s;
  for (size_t i = 0; i < n; ++i) s += digits[rng() & 15];
  return s;
}

}  // namespace

JobQueue::JobQueue(Store& store, const DataDir& data, Catalogue& catalogue, const JobRequests& requests,
                   Executor executor, uint64_t max_expanded_bytes)
    : store_(store),
      data_(data),
      catalogue_(catalogue),
      requests_(requests),
      executor_(std::move(executor)),
      max_expanded_bytes_(max_expanded_bytes) {}

JobQueue::~JobQueue() { stop(); }

// ---------------------------------------------------------------- lifecycle

void JobQueue::requeue_interrupted() {
  for (const auto& id : store_.requeue_running())
    spdlog::warn("job {} was running when the server stopped: re-queued (it continues from its checkpoints)", id);
  // Checkpoints of jobs that will not run again are leftovers.
  std::set<std::string> queued;
  for (const auto& j : store_.jobs())
    if (j.state == JobState::queued) queued.insert(j.id);
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(data_.work(), ec))
    if (!queued.count(e.path().filename().string())) fs::remove_all(e.path(), ec);
}

void JobQueue::set_maintenance(std::function<void()> task, std::chrono::milliseconds every) {
  std::lock_guard lock(mutex_);
  maintenance_ = std::move(task);
  maintenance_every_ = std::max(every, std::chrono::milliseconds(1));
  next_maintenance_ = std::chrono::steady_clock::now() + maintenance_every_;
}

void JobQueue::start(int workers) {
  for (int i = 0; i < workers; ++i) workers_.emplace_back([this] { worker_loop(); });
}

void JobQueue::stop() {
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

void JobQueue::notify() {
  ++revision_;
  change_cv_.notify_all();
}

uint64_t JobQueue::revision() {
  std::lock_guard lock(mutex_);
  return revision_;
}

uint64_t JobQueue::wait_for_change(uint64_t revision, std::chrono::milliseconds timeout) {
  std::unique_lock lock(mutex_);
  change_cv_.wait_for(lock, timeout, [&] { return revision_ != revision || stopping_; });
  return revision_;
}

std::map<std::string, double> JobQueue::stage_seconds() {
  std::lock_guard lock(mutex_);
  return stage_seconds_;
}

// ---------------------------------------------------------------- submission and views

json JobQueue::submit(const json& request) {
  JobRecord job;
  job.id = "j" + random_hex(15);
  job.spec = requests_.validate(request, job.id);
  job.database = job.spec["database"];
  job.created = now_seconds();
  {
    std::lock_guard lock(mutex_);
    if (stopping_) throw Error("unavailable", "the server is shutting down");
    job.seq = store_.insert_job(job);
    notify();
  }
  work_cv_.notify_all();
  spdlog::info("job {} queued for database {} ({} material(s))", job.id, job.database, job.spec["materials"].size());
  return this->job(job.id);
}

json JobQueue::job_json(const JobRecord& job) {
  json progress = job.progress.is_object() ? job.progress : json::object();
  if (auto it = live_.find(job.id); it != live_.end()) progress = it->second.progress;
  const double end = job.finished > 0 ? job.finished : now_seconds();
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
          // Set when a re-queued job continued from its checkpoints: the phase-3 tiles it kept.
          {"resumed_from_tile", progress.value("resumed_from_tile", json(nullptr))},
          // A target's search: which compression runs (null otherwise).
          {"attempt", progress.value("attempt", json(nullptr))},
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
json JobQueue::job(const std::string& id) {
  std::lock_guard lock(mutex_);
  auto record = store_.job(id);
  if (!record) throw NotFoundError("no job '" + id + "'");
  json j = job_json(*record);
  // A succeeded job's results: the reports of the materials it added, as the catalogue keeps them
  // with the version it published (here only, not in the list of jobs: one read of the versions).
  json results = nullptr;
  if (record->state == JobState::succeeded)
    for (const VersionRecord& v : store_.versions(record->database))
      if (v.version == record->version) {
        results = json::array();
        for (const auto& m : v.materials)
          if (m.value("job", "") == id) results.push_back({{"name", m["name"]}, {"report", m.value("report", json::object())}});
      }
  j["results"] = results;
  return j;
}

json JobQueue::jobs() {
  std::lock_guard lock(mutex_);
  json out = json::array();
  for (const auto& r : store_.jobs()) {
    json j = job_json(r);
    j.erase("request");
    out.push_back(j);
  }
  return out;
}

json JobQueue::cancel(const std::string& id) {
  {
    std::lock_guard lock(mutex_);
    auto record = store_.job(id);
    if (!record) throw NotFoundError("no job '" + id + "'");
    if (is_final(record->state)) throw ConflictError("job '" + id + "' is already " + to_string(record->state));
    if (record->state == JobState::queued) {
      store_.set_job_state(id, JobState::cancelled, json{{"code", "cancelled"}, {"message", "cancelled while queued"}}, 0,
                           now_seconds());
    } else if (auto it = live_.find(id); it != live_.end()) {
      it->second.cancel_requested = true;  // the executor notices at its next poll
    }
    notify();
  }
  spdlog::info("job {}: cancel requested", id);
  return job(id);
}

// ---------------------------------------------------------------- workers

std::optional<JobRecord> JobQueue::next_job() {
  for (auto& j : store_.jobs_in_state(JobState::queued))
    if (!busy_databases_.count(j.database)) return j;
  return std::nullopt;
}

bool JobQueue::maintenance_due() const {
  return maintenance_ && !maintaining_ && std::chrono::steady_clock::now() >= next_maintenance_;
}

void JobQueue::maintain() {
  try {
    maintenance_();
  } catch (const std::exception& e) {
    spdlog::warn("maintenance failed: {}", e.what());
  }
  std::lock_guard lock(mutex_);
  maintaining_ = false;
}

void JobQueue::worker_loop() {
  for (;;) {
    JobRecord job;
    {
      std::unique_lock lock(mutex_);
      std::optional<JobRecord> next;
      auto ready = [&] { return stopping_ || maintenance_due() || (next = next_job()).has_value(); };
      if (maintenance_) work_cv_.wait_until(lock, next_maintenance_, ready);
      else work_cv_.wait(lock, ready);
      if (stopping_) return;
      if (maintenance_due()) {
        // The next time is set now, so that the other workers wait for it rather than for this one.
        maintaining_ = true;
        next_maintenance_ = std::chrono::steady_clock::now() + maintenance_every_;
        lock.unlock();
        maintain();
        continue;
      }
      if (!next) continue;
      try {
        job = begin_running(*next);
      } catch (const std::exception& e) {
        // The store cannot record the start (a full disk): the job stays queued; try again shortly.
        spdlog::error("job {} cannot start: {}", next->id, e.what());
        work_cv_.wait_for(lock, std::chrono::seconds(1), [&] { return stopping_.load(); });
        continue;
      }
    }
    run(job);
    end_running(job);
    work_cv_.notify_all();
    release_freed_memory();
  }
}

// A compression frees its few hundred MiB when it ends, but glibc keeps freed memory in the arena
// that held it, and with the HTTP threads allocating in the same arenas meanwhile little of it was
// at the top of a heap where free() gives it back: the soak of bench/bench_soak.py measured the
// server's resident memory growing 55% from its 2nd to its 10th minute (243 MiB idle, 584 MiB at
// the end of 31 small jobs), of which malloc_trim gave back all but the live data. So after every
// job the free pages of every arena are returned to the system (madvise; the arenas stay).
void JobQueue::release_freed_memory() {
#ifdef __GLIBC__
  ::malloc_trim(0);
#endif
}

// The database is busy until end_running(): its next job waits, and so does its version number.
JobRecord JobQueue::begin_running(JobRecord job) {
  job.started = now_seconds();
  job.state = JobState::running;
  store_.set_job_state(job.id, JobState::running, nullptr, job.started, 0);  // first: it may throw
  busy_databases_.insert(job.database);
  Live live;
  live.stage_started = job.started;
  live_[job.id] = live;
  notify();
  return job;
}

void JobQueue::end_running(const JobRecord& job) {
  std::lock_guard lock(mutex_);
  busy_databases_.erase(job.database);
  if (auto it = live_.find(job.id); it != live_.end()) {
    finish_stage(it->second, now_seconds());
    live_.erase(it);
  }
  notify();
}

void JobQueue::finish_stage(Live& live, double now) {
  if (!live.stage.empty()) stage_seconds_[live.stage] += now - live.stage_started;
  live.stage_started = now;
}

void JobQueue::on_progress(const std::string& id, const JobProgress& p) {
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
                   {"material", p.material},
                   {"resumed_from_tile", p.resumed_tile >= 0 ? json(p.resumed_tile) : json(nullptr)}};
  if (!p.attempt.empty()) live.progress["attempt"] = p.attempt;
  if (stage_changed || now - live.last_persisted > 1.0) {
    store_.set_job_progress(id, live.progress);
    live.last_persisted = now;
  }
  notify();
}

bool JobQueue::cancel_requested(const std::string& id) {
  std::lock_guard lock(mutex_);
  auto it = live_.find(id);
  return it != live_.end() && it->second.cancel_requested;
}

JobContext JobQueue::context(const std::string& id, const NextVersion& next) {
  JobContext ctx;
  ctx.progress = [this, id](const JobProgress& p) { on_progress(id, p); };
  ctx.cancelled = [this, id] { return stopping_ || cancel_requested(id); };
  ctx.max_expanded_bytes = max_expanded_bytes_;
  ctx.existing_materials = next.existing;
  ctx.work_folder = data_.work(id).string();
  return ctx;
}

void JobQueue::run(const JobRecord& job) {
  NextVersion next;
  try {
    const JobSpec spec = requests_.spec(job);
    // No other job picks the same version number meanwhile: see begin_running().
    next = catalogue_.next_version(job.database);
    fs::create_directories(next.file.parent_path());
    JobContext ctx = context(job.id, next);
    spdlog::info("job {} running on database {}", job.id, job.database);
    executor_(spec, next.previous_file, next.file.string(), ctx);
    if (cancel_requested(job.id)) throw CancelledError("cancelled by request");
    if (stopping_) throw CancelledError("server shutting down");
    if (!fs::is_regular_file(next.file)) throw Error("internal", "the executor did not write the database");
    publish(job, spec, std::move(next.record), ctx.added);
    remove_checkpoints(ctx.work_folder);
    spdlog::info("job {} succeeded", job.id);
  } catch (const CancelledError& e) {
    if (stopping_ && !cancel_requested(job.id)) {
      spdlog::warn("job {} interrupted by shutdown: re-queued", job.id);
      end(job, JobState::queued, nullptr, next.file);
    } else {
      spdlog::info("job {} cancelled", job.id);
      end(job, JobState::cancelled, {{"code", "cancelled"}, {"message", e.what()}}, next.file);
    }
  } catch (const Error& e) {
    spdlog::warn("job {} failed: {}", job.id, e.what());
    end(job, JobState::failed, {{"code", e.code()}, {"message", e.what()}}, next.file);
  } catch (const fs::filesystem_error& e) {
    // A folder that cannot be made on a full disk is the same failure as a file that cannot be written.
    const bool full = is_no_space(e.code().value());
    spdlog::warn("job {} failed: {}", job.id, e.what());
    end(job, JobState::failed,
        {{"code", full ? "no_space" : "io"},
         {"message", std::string(e.what()) + (e.code().value() == ENOSPC ? " (ENOSPC)" : full ? " (EDQUOT)" : "")}},
        next.file);
  } catch (const std::exception& e) {
    spdlog::error("job {} failed: {}", job.id, e.what());
    end(job, JobState::failed, {{"code", "internal"}, {"message", e.what()}}, next.file);
  }
}

void JobQueue::publish(const JobRecord& job, const JobSpec& spec, VersionRecord next,
                       const std::vector<MaterialRecord>& added) {
  std::vector<MaterialRecord> records = added;
  if (records.empty())  // an executor that reports nothing still added the job's materials
    for (const auto& m : spec.materials) records.push_back({m.name, 0, 0, 0, json::object()});
  const VersionRecord v = catalogue_.describe(std::move(next), job.id, records);
  std::lock_guard lock(mutex_);
  if (auto it = live_.find(job.id); it != live_.end()) {
    it->second.progress["fraction"] = 1.0;
    store_.set_job_progress(job.id, it->second.progress);
  }
  store_.publish(v, now_seconds());  // the version and the job's success, in one transaction
}

// A cancel that came after the executor wrote, or an executor that failed after writing, must not
// leave a file where the version would be.
//
// The job's end is retried a few times, a moment apart: the disk may be full just now (the job's own
// failure may be why, and its removed output frees the space), and a lost end would leave the job
// 'running' until the next start re-queues it.
void JobQueue::end(const JobRecord& job, JobState state, const json& error, const fs::path& output) {
  std::error_code ec;
  if (!output.empty()) fs::remove(output, ec);
  if (state != JobState::queued) remove_checkpoints(data_.work(job.id).string());
  const bool requeued = state == JobState::queued;
  const double finished = requeued ? 0 : now_seconds();
  constexpr int kAttempts = 5;
  for (int attempt = 1;; ++attempt) {
    try {
      std::lock_guard lock(mutex_);
      store_.set_job_state(job.id, state, error, requeued ? 0 : job.started, finished);
      break;
    } catch (const std::exception& e) {
      if (attempt == kAttempts) {
        spdlog::error("job {}: its end ({}) could not be recorded in {} attempts: {}", job.id, to_string(state),
                      kAttempts, e.what());
        return;
      }
      spdlog::warn("job {}: recording its end failed (attempt {} of {}): {}", job.id, attempt, kAttempts, e.what());
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100) * (1 << attempt));
  }
  try {  // the last progress is only a detail of the record: not worth another wait
    std::lock_guard lock(mutex_);
    if (auto it = live_.find(job.id); it != live_.end()) store_.set_job_progress(job.id, it->second.progress);
  } catch (const std::exception& e) {
    spdlog::warn("job {}: its last progress was not recorded: {}", job.id, e.what());
  }
}

}  // namespace btfvq::server
