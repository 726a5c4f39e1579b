#pragma once
// The job queue and its workers. The oldest queued job whose database is idle runs next: FIFO per
// database, parallel across databases up to the worker count. A job runs the Executor into the
// file of its database's next version and publishes it if it succeeds. Progress lives here while
// a job runs and reaches the store now and then, so that a restarted server shows where a job was.
#include <nlohmann/json.hpp>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "server/catalogue.h"
#include "server/data_dir.h"
#include "server/executor.h"
#include "server/job_request.h"
#include "server/store.h"

namespace btfvq::server {

class JobQueue {
 public:
  JobQueue(Store& store, const DataDir& data, Catalogue& catalogue, const JobRequests& requests, Executor executor,
           uint64_t max_expanded_bytes);
  ~JobQueue();

  // Jobs left running by a killed server go back to the queue; they continue from their checkpoints
  // (DataDir::work), and the checkpoints of jobs that are not queued are removed.
  void requeue_interrupted();
  // Work that an idle worker does every `every` (the sweep of abandoned uploads): between jobs, one
  // worker at a time, so that it needs no thread of its own. Set before start().
  void set_maintenance(std::function<void()> task, std::chrono::milliseconds every);
  void start(int workers);
  // Stops the workers; running jobs are interrupted and go back to 'queued' for the next start.
  void stop();
  bool stopping() const { return stopping_; }

  // Validates the request (JobRequests) before it changes any state, then queues the job.
  nlohmann::json submit(const nlohmann::json& request);
  nlohmann::json job(const std::string& id);
  nlohmann::json jobs();
  nlohmann::json cancel(const std::string& id);

  // Change notification for event streams: blocks until something changed after `revision` or
  // `timeout` passed; returns the current revision.
  uint64_t wait_for_change(uint64_t revision, std::chrono::milliseconds timeout);
  uint64_t revision();

  // Seconds that jobs spent in each stage, for the metrics.
  std::map<std::string, double> stage_seconds();

 private:
  // A running job: what the store does not hold, or holds only now and then.
  struct Live {
    nlohmann::json progress = nlohmann::json::object();
    bool cancel_requested = false;
    std::string stage;
    double stage_started = 0;
    double last_persisted = 0;
  };

  void worker_loop();
  bool maintenance_due() const;  // under mutex_
  void maintain();
  std::optional<JobRecord> next_job();    // under mutex_
  JobRecord begin_running(JobRecord job);  // under mutex_
  void end_running(const JobRecord& job);
  // Gives the memory that a finished job freed back to the system (glibc keeps it otherwise).
  static void release_freed_memory();
  void run(const JobRecord& job);
  JobContext context(const std::string& id, const NextVersion& next);
  void publish(const JobRecord& job, const JobSpec& spec, VersionRecord next, const std::vector<MaterialRecord>& added);
  void end(const JobRecord& job, JobState state, const nlohmann::json& error, const std::filesystem::path& output);
  bool cancel_requested(const std::string& id);
  void on_progress(const std::string& id, const JobProgress& p);
  void finish_stage(Live& live, double now);     // under mutex_
  void notify();                                 // under mutex_
  nlohmann::json job_json(const JobRecord& job);  // under mutex_

  Store& store_;
  const DataDir& data_;
  Catalogue& catalogue_;
  const JobRequests& requests_;
  Executor executor_;
  uint64_t max_expanded_bytes_;

  std::mutex mutex_;
  std::condition_variable work_cv_, change_cv_;
  std::vector<std::thread> workers_;
  std::set<std::string> busy_databases_;
  std::map<std::string, Live> live_;
  std::atomic<bool> stopping_{false};
  uint64_t revision_ = 0;
  std::map<std::string, double> stage_seconds_;
  std::function<void()> maintenance_;
  std::chrono::milliseconds maintenance_every_{0};
  std::chrono::steady_clock::time_point next_maintenance_;
  bool maintaining_ = false;
};

}  // namespace btfvq::server
