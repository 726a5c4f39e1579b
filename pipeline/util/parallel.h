#pragma once
// The one way the library spreads a loop over cores: a process-wide pool of worker threads, made on
// first use and kept, so a loop pays no thread start-up and every loop shares the same cores (two
// jobs of the server no longer start two sets of threads each). The calling thread works too.
//
// Results must not depend on the threads: each index writes its own output, and a reduction keeps
// per-slot or per-chunk partials that the caller combines in a fixed order.
#include <cstddef>
#include <functional>
#include <type_traits>

namespace btfvq {

struct ParallelOptions {
  // At most this many threads on this call, the caller included; 0 is every thread of the pool.
  // Callers with a configured count (schedule.threads, --threads) pass it here.
  size_t threads = 0;
  // Indices per chunk, the unit a thread claims; 0 picks about eight chunks per thread.
  size_t grain = 0;
};

// Threads a call can use at most: hardware_concurrency (at least 1), the caller being one of them.
size_t parallel_threads();

// Threads, hence worker slots, a call over n indices uses at most (at least 1), so that a caller
// can make per-slot scratch before the call.
size_t parallel_slots(size_t n, const ParallelOptions& options = {});

// At most `parts` contiguous chunks of about n / parts indices, for work that wants few long runs.
ParallelOptions in_parts(size_t n, size_t parts);

namespace detail {
using ChunkBody = std::function<void(size_t begin, size_t end, size_t slot)>;
void run_chunks(size_t begin, size_t end, const ParallelOptions& options, const ChunkBody& body);
}  // namespace detail

// Runs body over [begin, end) and returns when all of it ran. body is one of
//   body(i)                 once per index,
//   body(first, last)       once per chunk [first, last),
//   body(first, last, slot) once per chunk; slot in [0, parallel_slots(end - begin, options)) is
//                           the worker's, the same for all chunks one thread runs in this call.
// The first exception a body throws is rethrown here and the chunks not yet started are skipped.
// A call from inside a body, or with options.threads == 1, runs on the calling thread in order.
template <class Body>
void parallel_for(size_t begin, size_t end, Body&& body, const ParallelOptions& options = {}) {
  if constexpr (std::is_invocable_v<Body&, size_t, size_t, size_t>) {
    detail::run_chunks(begin, end, options, [&body](size_t b, size_t e, size_t slot) { body(b, e, slot); });
  } else if constexpr (std::is_invocable_v<Body&, size_t, size_t>) {
    detail::run_chunks(begin, end, options, [&body](size_t b, size_t e, size_t) { body(b, e); });
  } else {
    static_assert(std::is_invocable_v<Body&, size_t>, "parallel_for: body(i), body(first, last) or body(first, last, slot)");
    detail::run_chunks(begin, end, options, [&body](size_t b, size_t e, size_t) {
      for (size_t i = b; i < e; ++i) body(i);
    });
  }
}

}  // namespace btfvq
