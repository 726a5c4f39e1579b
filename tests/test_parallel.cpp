// The one thread pool (pipeline/util/parallel.h): every index runs once, errors come back to the
// caller, nesting and concurrent callers cannot deadlock, a cap of one stays on the calling thread.
#include <doctest/doctest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <numeric>
#include <stdexcept>
#include <thread>
#include <vector>

#include "pipeline/util/parallel.h"

using namespace btfvq;

namespace {

// How often each index of [0, n) ran, for one call with these options.
std::vector<int> run_counts(size_t n, const ParallelOptions& options) {
  std::unique_ptr<std::atomic<int>[]> hits(new std::atomic<int>[n + 1]());
  parallel_for(0, n, [&](size_t i) { hits[i]++; }, options);
  std::vector<int> out(n);
  for (size_t i = 0; i < n; ++i) out[i] = hits[i];
  return out;
}

const size_t kSizes[] = {0, 1, 2, 3, 7, 8, 63, 64, 65, 1000, 4097};
const size_t kCaps[] = {0, 1, 2, 3, 16};
const size_t kGrains[] = {0, 1, 5, 1000};

}  // namespace

TEST_CASE("parallel_for runs every index exactly once whatever the size, cap and grain") {
  for (size_t n : kSizes)
    for (size_t cap : kCaps)
      for (size_t grain : kGrains) {
        CAPTURE(n);
        CAPTURE(cap);
        CAPTURE(grain);
        CHECK(run_counts(n, {.threads = cap, .grain = grain}) == std::vector<int>(n, 1));
      }
}

TEST_CASE("chunks tile the range and a slot is held by one thread at a time") {
  for (size_t n : kSizes)
    for (size_t cap : kCaps) {
      const ParallelOptions options{.threads = cap, .grain = 3};
      const size_t slots = parallel_slots(n, options);
      CHECK(slots >= 1);
      CHECK(slots <= parallel_threads());
      std::vector<std::atomic<int>> busy(slots);
      std::atomic<bool> clash{false}, out_of_range{false};
      std::atomic<size_t> covered{0};
      parallel_for(10, 10 + n, [&](size_t first, size_t last, size_t slot) {
        if (slot >= slots || first >= last || first < 10 || last > 10 + n) {
          out_of_range = true;
          return;
        }
        if (busy[slot]++ != 0) clash = true;
        covered += last - first;
        busy[slot]--;
      }, options);
      CHECK_FALSE(out_of_range);
      CHECK_FALSE(clash);
      CHECK(covered == n);
    }
}

TEST_CASE("in_parts splits into at most that many contiguous chunks") {
  for (size_t n : {1, 9, 10, 11, 100000})
    for (size_t parts : {1, 2, 3, 16}) {
      std::mutex mutex;
      std::vector<std::pair<size_t, size_t>> chunks;
      parallel_for(0, n, [&](size_t first, size_t last) {
        std::lock_guard lock(mutex);
        chunks.emplace_back(first, last);
      }, in_parts(n, parts));
      CHECK(chunks.size() <= parts);
      std::sort(chunks.begin(), chunks.end());
      size_t next = 0;
      for (const auto& [first, last] : chunks) {
        CHECK(first == next);
        next = last;
      }
      CHECK(next == n);
    }
}

TEST_CASE("an exception reaches the caller, the rest is abandoned, and the pool stays usable") {
  std::atomic<size_t> ran{0};
  const auto body = [&](size_t i) {
    ++ran;
    if (i == 0) throw std::runtime_error("index 0");
    std::this_thread::sleep_for(std::chrono::microseconds(20));
  };
  CHECK_THROWS_WITH_AS(parallel_for(0, 10000, body, {.grain = 1}), "index 0", std::runtime_error);
  CHECK(ran < 5000);
  // Every index throws: one of them comes back, whichever thread was first.
  CHECK_THROWS_AS(parallel_for(0, 100, [](size_t) { throw std::logic_error("each"); }), std::logic_error);
  CHECK_THROWS_AS(parallel_for(0, 100, [](size_t) { throw std::logic_error("each"); }, {.threads = 1}),
                  std::logic_error);
  CHECK(run_counts(5000, {}) == std::vector<int>(5000, 1));
}

TEST_CASE("a nested parallel_for completes and runs on the thread of its outer body") {
  std::atomic<size_t> total{0};
  std::atomic<bool> moved{false}, wide{false};
  parallel_for(0, 16, [&](size_t) {
    const auto outer = std::this_thread::get_id();
    if (parallel_slots(100) != 1) wide = true;
    parallel_for(0, 100, [&](size_t) {
      if (std::this_thread::get_id() != outer) moved = true;
      ++total;
    }, {.grain = 1});
  }, {.grain = 1});
  CHECK(total == 1600);
  CHECK_FALSE(moved);
  CHECK_FALSE(wide);
}

TEST_CASE("a cap of one thread runs every chunk on the calling thread, in order") {
  const auto caller = std::this_thread::get_id();
  std::vector<size_t> order;
  bool elsewhere = false;
  CHECK(parallel_slots(1000, {.threads = 1}) == 1);
  parallel_for(0, 1000, [&](size_t i) {
    elsewhere = elsewhere || std::this_thread::get_id() != caller;
    order.push_back(i);
  }, {.threads = 1, .grain = 7});
  CHECK_FALSE(elsewhere);
  std::vector<size_t> expected(1000);
  std::iota(expected.begin(), expected.end(), 0);
  CHECK(order == expected);
}

TEST_CASE("two indices run at once when the pool has a second thread") {
  if (parallel_threads() < 2) return;
  std::mutex mutex;
  std::condition_variable cv;
  int arrived = 0;
  bool met = true;
  parallel_for(0, 2, [&](size_t) {
    std::unique_lock lock(mutex);
    ++arrived;
    cv.notify_all();
    met = cv.wait_for(lock, std::chrono::seconds(20), [&] { return arrived == 2; }) && met;
  }, {.threads = 2, .grain = 1});
  CHECK(met);
}

TEST_CASE("several threads calling parallel_for at once all complete") {
  constexpr size_t kCallers = 6, kCalls = 40, kSize = 3000;
  std::vector<size_t> sums(kCallers, 0);
  std::vector<std::thread> callers;
  for (size_t c = 0; c < kCallers; ++c)
    callers.emplace_back([&, c] {
      for (size_t k = 0; k < kCalls; ++k) {
        std::vector<size_t> out(kSize, 0);
        parallel_for(0, kSize, [&](size_t i) { out[i] = i; }, {.threads = 1 + c % 3});
        sums[c] += std::accumulate(out.begin(), out.end(), size_t(0));
      }
    });
  for (auto& t : callers) t.join();
  CHECK(sums == std::vector<size_t>(kCallers, kCalls * (kSize * (kSize - 1) / 2)));
}
