#include "pipeline/util/parallel.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

namespace btfvq {

namespace {

// Set on the pool's threads and on a caller while it runs chunks. A parallel_for from there runs
// inline: the outer loop already keeps the pool busy, so handing chunks over would only add waits.
thread_local bool inside_body = false;

class InsideBody {
 public:
  InsideBody() : was_(inside_body) { inside_body = true; }
  ~InsideBody() { inside_body = was_; }
  InsideBody(const InsideBody&) = delete;
  InsideBody& operator=(const InsideBody&) = delete;

 private:
  bool was_;
};

size_t ceil_div(size_t n, size_t d) { return n / d + (n % d != 0); }

size_t thread_cap(const ParallelOptions& options) {
  return options.threads > 0 ? std::min(options.threads, parallel_threads()) : parallel_threads();
}

// Eight chunks per thread by default: enough for uneven indices to even out, few enough that
// claiming a chunk costs nothing next to running it.
size_t grain_of(size_t n, const ParallelOptions& options) {
  return options.grain > 0 ? options.grain : std::max<size_t>(1, n / (8 * thread_cap(options)));
}

// One call's loop. The fields after `body` are shared between the threads that run it; `joined` and
// `active` are changed under the pool's mutex (`active` is read without it by a polling caller).
struct Job {
  size_t begin, end, grain, chunks, max_threads;
  const detail::ChunkBody& body;
  std::atomic<size_t> next_chunk{0};
  std::atomic<bool> failed{false};
  std::mutex error_mutex;
  std::exception_ptr error;
  size_t joined = 1;  // the caller holds slot 0
  std::atomic<size_t> active{0};  // pool threads inside work()
  std::condition_variable helpers_done;

  bool open() const { return joined < max_threads && !failed && next_chunk.load() < chunks; }

  void work(size_t slot) {
    for (size_t c; !failed.load(std::memory_order_relaxed) && (c = next_chunk.fetch_add(1)) < chunks;) {
      const size_t first = begin + c * grain;
      try {
        body(first, first + std::min(grain, end - first), slot);
      } catch (...) {
        fail(std::current_exception());
      }
    }
  }

  void fail(std::exception_ptr e) {
    std::lock_guard lock(error_mutex);
    if (!error) error = std::move(e);
    failed = true;
  }
};

// hardware_concurrency - 1 threads that wait for a call to publish a job with room for them (polling
// for kPoll after their last job, then asleep). Made once and never destroyed: joining at exit would race static destructors and hang a forked child.
class Pool {
 public:
  explicit Pool(size_t helpers) {
    for (size_t i = 0; i < helpers; ++i) threads_.emplace_back([this] { serve(); });
  }

  static Pool& get() {
    static Pool* pool = new Pool(parallel_threads() - 1);
    return *pool;
  }

  void run(Job& job) {
    publish(job);
    {
      InsideBody inside;
      job.work(0);
    }
    std::unique_lock lock(mutex_);
    jobs_.erase(std::find(jobs_.begin(), jobs_.end(), &job));
    if (job.active > 0) {
      // No helper joins from here on; those inside finish their chunks about now, so poll before
      // sleeping (see wait_for_job), then take the mutex, which a helper holds until it is done with
      // the job.
      lock.unlock();
      poll_until([&] { return job.active.load(std::memory_order_acquire) == 0; });
      lock.lock();
    }
    job.helpers_done.wait(lock, [&] { return job.active == 0; });
  }

 private:
  void publish(Job& job) {
    {
      std::lock_guard lock(mutex_);
      jobs_.push_back(&job);
      published_.fetch_add(1, std::memory_order_release);
    }
    wake_.notify_all();
  }

  // Waits (mutex held on entry and return) until a job has room. A helper polls for a while before
  // it sleeps: the growing phases publish small jobs back to back (a few tens of microseconds of
  // work each), and waking a sleeping thread takes about as long on a virtual machine (measured
  // here: a call of two 8-microsecond chunks took 34 microseconds with a sleeping helper).
  Job* wait_for_job(std::unique_lock<std::mutex>& lock) {
    if (Job* job = open_job()) return job;
    const uint64_t seen = published_.load(std::memory_order_acquire);
    lock.unlock();
    poll_until([&] { return published_.load(std::memory_order_acquire) != seen; });
    lock.lock();
    Job* job = nullptr;
    wake_.wait(lock, [&] { return (job = open_job()) != nullptr; });
    return job;
  }

  Job* open_job() const {
    for (Job* job : jobs_)
      if (job->open()) return job;
    return nullptr;
  }

  void serve() {
    inside_body = true;
    std::unique_lock lock(mutex_);
    for (;;) {
      Job* job = wait_for_job(lock);
      const size_t slot = job->joined++;
      ++job->active;
      lock.unlock();
      job->work(slot);
      lock.lock();
      // Under the mutex: the caller may return, and free the job, as soon as it sees active == 0.
      if (--job->active == 0) job->helpers_done.notify_all();
    }
  }

  static constexpr std::chrono::microseconds kPoll{100};
  template <class Done>
  static void poll_until(Done done) {
    const auto until = std::chrono::steady_clock::now() + kPoll;
    while (!done() && std::chrono::steady_clock::now() < until) {
    }
  }
  std::mutex mutex_;
  std::condition_variable wake_;
  std::atomic<uint64_t> published_{0};  // jobs published so far: what a polling helper watches
  std::vector<Job*> jobs_;  // calls under way, oldest first
  std::vector<std::thread> threads_;
};

void run_inline(size_t begin, size_t end, size_t grain, const detail::ChunkBody& body) {
  for (size_t first = begin; first < end; first += std::min(grain, end - first))
    body(first, first + std::min(grain, end - first), 0);
}

}  // namespace

size_t parallel_threads() {
  static const size_t threads = std::max(1u, std::thread::hardware_concurrency());
  return threads;
}

size_t parallel_slots(size_t n, const ParallelOptions& options) {
  if (inside_body) return 1;
  return std::max<size_t>(1, std::min(thread_cap(options), ceil_div(n, grain_of(n, options))));
}

ParallelOptions in_parts(size_t n, size_t parts) {
  parts = std::max<size_t>(1, parts);
  return {.threads = parts, .grain = std::max<size_t>(1, ceil_div(n, parts))};
}

namespace detail {

void run_chunks(size_t begin, size_t end, const ParallelOptions& options, const ChunkBody& body) {
  if (end <= begin) return;
  const size_t n = end - begin, grain = grain_of(n, options), threads = parallel_slots(n, options);
  if (threads == 1) return run_inline(begin, end, grain, body);
  Job job{begin, end, grain, ceil_div(n, grain), threads, body};
  Pool::get().run(job);
  if (job.error) std::rethrow_exception(job.error);
}

}  // namespace detail

}  // namespace btfvq
