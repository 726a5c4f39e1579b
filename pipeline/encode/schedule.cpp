#include "pipeline/encode/schedule.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <memory>

#include <btfvq/error.h>
#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/util/parallel.h"

namespace btfvq {

ScheduleSettings ScheduleSettings::from(const ParameterDictionary& d) {
  ScheduleSettings s;
  s.phase1_fraction = d.number("schedule.phase1_fraction", 0.0, 1.0);
  s.phase2_fraction = d.number("schedule.phase2_fraction", 0.0, 1.0);
  if (s.phase1_fraction + s.phase2_fraction > 1.0)
    throw ConfigError(d.origin() + ": 'schedule.phase1_fraction' + 'schedule.phase2_fraction' must not exceed 1");
  s.relax_factor = d.number("schedule.relax_factor", 1.0, 100.0);
  s.tile_texels = d.integer("schedule.tile_texels", 1, 1 << 16);
  s.threads = d.integer("schedule.threads", 1, 256);
  s.search = d.string("schedule.search");
  s.assign_metric = metric_from(d, "schedule.assign_metric");
  s.assign_thresholds = Thresholds::from(d, s.assign_metric);
  s.compose_threshold = d.number("schedule.compose_threshold", 0.0, 1e6);
  s.compose_gain = d.number("schedule.compose_gain", 0.0, 1e6);
  s.compose_p3 = d.boolean("schedule.compose_p3");
  s.compose_p3_share = d.number("schedule.compose_p3_share", 0.0, 1.0);
  s.refine = RefineSettings::from(d);
  if (s.search != "auto" && s.search != "pruned" && s.search != "batched" && s.search != "batched-reference")
    throw ConfigError(d.origin() + ": 'schedule.search' = '" + s.search +
                      "' must be \"auto\", \"pruned\", \"batched\" or \"batched-reference\"");
  return s;
}

ScheduleSettings ScheduleSettings::defaults() { return from(ParameterDictionary::embedded_default("pipeline")); }

SearchPath ScheduleSettings::search_path(const AngularGrid& grid, const SimilaritySettings& similarity) const {
  if (search == "pruned") return SearchPath::Pruned;
  if (search == "batched-reference") return SearchPath::BatchedReference;
  if (search == "batched")
    return ComputeDevice::get().uses_opencl() ? SearchPath::BatchedOpenCL : SearchPath::BatchedReference;
  return FrozenSearch::preferred(grid, similarity);
}

namespace {

double radical_inverse(uint64_t i, uint32_t base) {
  double inv = 1.0 / base, f = inv, r = 0;
  while (i > 0) {
    r += f * double(i % base);
    i /= base;
    f *= inv;
  }
  return r;
}

}  // namespace

std::vector<uint32_t> halton_order(int width, int height) {
  if (width <= 0 || height <= 0) throw InputError("halton_order: width and height must be positive");
  const size_t n = size_t(width) * size_t(height);
  std::vector<uint32_t> order;
  order.reserve(n);
  std::vector<uint8_t> seen(n, 0);
  for (uint64_t i = 1; order.size() < n && i <= 16 * uint64_t(n) + 16; ++i) {
    const int x = std::min(width - 1, int(radical_inverse(i, 2) * width));
    const int y = std::min(height - 1, int(radical_inverse(i, 3) * height));
    const size_t id = size_t(y) * size_t(width) + size_t(x);
    if (!seen[id]) {
      seen[id] = 1;
      order.push_back(uint32_t(id));
    }
  }
  for (size_t id = 0; id < n; ++id)
    if (!seen[id]) order.push_back(uint32_t(id));
  return order;
}

namespace {

// Whether the texel at position j of the Halton order is among an evenly spread share s of them:
// a function of the position alone, so the same on every tile split, thread count and resume.
bool in_share(size_t j, double s) { return std::floor(double(j + 1) * s) > std::floor(double(j) * s); }

// CPU seconds of the whole process: over a phase, divided by its wall seconds, how many cores it kept busy.
double process_cpu_seconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return double(t.tv_sec) + 1e-9 * double(t.tv_nsec);
}

}  // namespace

void phase_sizes(size_t texels, const ScheduleSettings& s, size_t* phase1, size_t* phase2) {
  size_t a = size_t(std::llround(s.phase1_fraction * double(texels)));
  a = std::clamp<size_t>(a, texels > 0 ? 1 : 0, texels);
  size_t b = size_t(std::llround(s.phase2_fraction * double(texels)));
  b = std::min(b, texels - a);
  *phase1 = a;
  *phase2 = b;
}

size_t phase3_tile_count(size_t texels, const ScheduleSettings& s, size_t* first_texel) {
  size_t n1, n2;
  phase_sizes(texels, s, &n1, &n2);
  const bool refining = s.refine.iterations > 0 && n1 + n2 > 0;  // as run_schedule decides it
  const size_t from = refining ? 0 : n1 + n2, tile = size_t(s.tile_texels);
  if (first_texel) *first_texel = from;
  return (texels - from + tile - 1) / tile;
}

ScheduleResult run_schedule(Codebooks& books, Dynamic dyn, int width, int height, const TexelSource& source,
                            const Thresholds& thresholds, const SimilaritySettings& similarity,
                            const ScheduleSettings& schedule, const std::function<void(const ScheduleProgress&)>& progress,
                            const std::function<bool()>& cancelled, const ScheduleCheckpoints& checkpoints) {
  if (!source) throw InputError("run_schedule: no texel source");
  const std::vector<uint32_t> order = halton_order(width, height);
  const size_t total = order.size(), samples = books.grid.samples();
  size_t n1, n2;
  phase_sizes(total, schedule, &n1, &n2);

  // With a refinement, phase 3 assigns every texel: the growing phases' own assignments predate it.
  const bool refining = schedule.refine.iterations > 0 && n1 + n2 > 0;
  const size_t bounds[4] = {0, n1, n1 + n2, total};
  const size_t phase3_from = refining ? 0 : bounds[2];
  const size_t refine_texels = std::max(bounds[2], size_t(std::llround(schedule.refine.fraction * double(total))));

  const PhaseThreeState* resume = checkpoints.resume;
  ScheduleResult result;
  result.p6_index.assign(total, -1);
  result.p6_scale.assign(total, 0.0f);
  result.dissimilarity.assign(total, 0.0f);
  if (resume) {
    if (resume->result.p6_index.size() != total) throw InputError("run_schedule: the checkpoint is of another sample");
    result = resume->result;
  }
  const CodebookSizes first = CodebookSizes::of(books);  // rows of earlier materials are not refined
  EncoderStats grown = resume ? resume->result.report.encoder : EncoderStats{};  // of encoders replaced
  // A resumed run starts in phase 3, with the thresholds the growing phases ended with.
  auto make_encoder = [&](const Thresholds& t, const SimilaritySettings& sim) {
    auto e = std::make_unique<Encoder>(books, dyn, t, sim);
    e->set_threads(size_t(schedule.threads));
    return e;
  };
  // The refinement and phase 3 choose entries by schedule.assign_metric with its thresholds
  // (schedule.assign_thresholds, relaxed as phase 2's): always an encoder of their own, so that an
  // uninterrupted run and a resumed one assign with the same one whatever the metrics.
  SimilaritySettings assign_similarity = similarity;
  assign_similarity.metric = schedule.assign_metric;
  const Thresholds assign_thresholds =
      n2 > 0 ? schedule.assign_thresholds.relaxed(schedule.relax_factor) : schedule.assign_thresholds;
  auto make_assigner = [&] { return make_encoder(assign_thresholds, assign_similarity); };
  auto encoder = resume ? make_assigner() : make_encoder(thresholds, similarity);
  bool assigning = resume != nullptr;
  auto start_assigning = [&] {
    if (assigning) return;
    assigning = true;
    grown.add(encoder->stats());
    encoder = make_assigner();
  };
  const size_t tile = size_t(schedule.tile_texels);
  const SearchPath path = schedule.search_path(books.grid, assign_similarity);
  std::unique_ptr<FrozenSearch> frozen;  // built when phase 3 starts: the code-books are final then

  // Lloyd iterations on the first refine_texels texels in Halton order: assign (the phase-3
  // search, run by refine_step on each tile in its first pass, so the texels are resampled once for
  // both) and update (refine_step); the encoder is rebuilt after each update, as its caches hold
  // the moved rows.
  auto refine = [&] {
    const auto t = std::chrono::steady_clock::now();
    Assignment as;
    as.ids.assign(order.begin(), order.begin() + ptrdiff_t(refine_texels));
    as.p4.resize(refine_texels);
    as.scale.resize(refine_texels);
    std::vector<P6Entry> entries;
    start_assigning();
    for (int it = 0; it < schedule.refine.iterations; ++it) {
      if (progress) progress({2, true, size_t(it), size_t(schedule.refine.iterations), CodebookSizes::of(books)});
      FrozenSearch search(*encoder, path, schedule.threads);
      auto assign = [&](const float* x, size_t n, uint32_t* p4, float* scale) {
        if (cancelled && cancelled()) throw CancelledError("encoding cancelled in the refinement");
        entries.resize(n);
        search.encode(x, n, entries.data());
        for (size_t i = 0; i < n; ++i) {
          p4[i] = entries[i].index;
          scale[i] = entries[i].scale;
        }
      };
      const RefineStep step = refine_step(books, first, dyn, as, source, tile, it == 0 ? schedule.refine.merge : RefineMerge{},
                                          size_t(schedule.threads), assign);
      result.report.refine.push_back(step);
      grown.add(encoder->stats());
      encoder = make_assigner();
      if (!(step.mse_before - step.mse_after > schedule.refine.min_gain * step.mse_before)) break;
    }
    result.report.refine_texels = refine_texels;
    result.report.refine_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
  };

  // Tiles of consecutive texels in Halton order, never crossing a phase boundary. The next tile is
  // resampled on another thread while the current one is encoded (phases 1 and 2 grow the
  // code-books on one thread), so memory holds two tiles of resampled texels at most.
  struct Tile {
    int phase;
    size_t at, n;
  };
  std::vector<Tile> tiles;
  for (int phase = 1; phase <= 3; ++phase)
    for (size_t at = phase == 3 ? phase3_from : bounds[phase - 1]; at < bounds[phase]; at += tile)
      tiles.push_back({phase, at, std::min(tile, bounds[phase] - at)});
  const size_t first_phase3 = size_t(std::count_if(tiles.begin(), tiles.end(), [](const Tile& t) { return t.phase < 3; }));
  const size_t start = resume ? std::min(tiles.size(), first_phase3 + resume->tiles_done) : 0;
  TilePrefetch prefetch(source, 3 * samples);
  auto fetch = [&](size_t k) { prefetch.fetch(order.data() + tiles[k].at, tiles[k].n); };
  if (start < tiles.size()) fetch(start);

  auto t0 = std::chrono::steady_clock::now();
  double cpu0 = process_cpu_seconds();
  for (size_t k = start; k < tiles.size(); ++k) {
    const auto [phase, at, n] = tiles[k];
    const float* texels = prefetch.take();  // the tile's texels (rethrows the source's error)
    if (cancelled && cancelled()) throw CancelledError("encoding cancelled in phase " + std::to_string(phase));
    const size_t from = phase == 3 ? phase3_from : bounds[phase - 1];
    if (phase == 3 && at == from && refining && !resume) refine();  // before the next prefetch: one source call at a time
    if (k + 1 < tiles.size()) fetch(k + 1);
    if (at == from || k == start) {
      t0 = std::chrono::steady_clock::now();
      cpu0 = process_cpu_seconds();
      if (phase == 2 && at == from) encoder->set_thresholds(thresholds.relaxed(schedule.relax_factor));
    }
    if (phase == 3 && at == from && !resume && checkpoints.save) {  // the code-book version
      result.report.encoder = grown;
      result.report.encoder.add(encoder->stats());
      checkpoints.save(0, result, {});
    }
    auto store = [&](size_t i, const P6Entry& e) {
      const uint32_t id = order[at + i];
      result.p6_index[id] = int32_t(e.index);
      result.p6_scale[id] = e.scale;
      result.dissimilarity[id] = float(e.dissimilarity);
    };
    if (phase < 3) {
      for (size_t i = 0; i < n; ++i) store(i, encoder->encode_growing(texels + i * 3 * samples));
    } else {
      if (!frozen) {
        start_assigning();
        frozen = std::make_unique<FrozenSearch>(*encoder, path, schedule.threads);
      }
      std::vector<P6Entry> entries(n);
      frozen->encode(texels, n, entries.data());
      // Proposals in parallel (they read only the frozen P3 and below), adoption in texel order: an
      // adopted entry is seen by the texels after it, and the result depends neither on the device
      // nor on the number of threads.
      std::vector<size_t> todo;
      for (size_t i = 0; i < n; ++i)
        if (entries[i].dissimilarity > schedule.compose_threshold) todo.push_back(i);
      const auto t_propose = std::chrono::steady_clock::now();
      std::vector<P4Proposal> proposals(todo.size());
      std::vector<char> proposed(todo.size());
      parallel_for(0, todo.size(), [&](size_t k) {
        proposed[k] = encoder->propose_p4(texels + todo[k] * 3 * samples, &proposals[k],
                                           schedule.compose_p3 && in_share(at + todo[k], schedule.compose_p3_share));
      }, ParallelOptions{size_t(schedule.threads), 1});
      const auto t_adopt = std::chrono::steady_clock::now();
      result.report.propose_seconds += std::chrono::duration<double>(t_adopt - t_propose).count();
      const uint32_t tile_start = uint32_t(books.p4_index.rows());
      std::vector<std::pair<uint32_t, size_t>> added;  // (entry, the proposal it was)
      for (size_t k = 0; k < todo.size(); ++k) {
        if (!proposed[k]) continue;
        P6Entry& e = entries[todo[k]];
        // The entries adopted earlier in this tile, which the batch did not see: those made of the
        // same P3 entries in at least half of the groups (a texel close to an adopted entry picks
        // mostly its P3 entries too); scoring every one would cost adopted^2 per tile. New P3 rows
        // (numbered within their proposal) count as different.
        std::vector<uint32_t> near;
        for (const auto& [entry, from] : added) {
          size_t same = 0;
          for (size_t p = 0; p < proposals[k].p3.size(); ++p)
            same += !proposals[k].is_new(p) && proposals[from].p3[p] == proposals[k].p3[p];
          if (2 * same >= proposals[k].p3.size()) near.push_back(entry);
        }
        if (!near.empty()) {
          try {
            const P6Entry a = encoder->encode_frozen_among(texels + todo[k] * 3 * samples, near,
                                                          dissimilarity_to_score(schedule.assign_metric, e.dissimilarity, 3 * samples));
            if (a.dissimilarity < e.dissimilarity) e = a;
          } catch (const InputError&) {  // none is closer
          }
          if (e.dissimilarity <= schedule.compose_threshold) continue;
        }
        if (!(proposals[k].entry.dissimilarity < e.dissimilarity - schedule.compose_gain)) continue;
        const uint32_t before = uint32_t(books.p4_index.rows());
        e = encoder->adopt_p4(proposals[k]);
        if (books.p4_index.rows() > before) {
          added.push_back({e.index, k});
          ++result.report.composed;
        }
      }
      result.report.adopt_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t_adopt).count();
      if (books.p4_index.rows() > tile_start) frozen->sync();
      for (size_t i = 0; i < n; ++i) store(i, entries[i]);
      if (checkpoints.save) checkpoints.save(k + 1 - first_phase3, result, {order.data() + at, n});
    }
    if (progress) progress({phase, false, at + n - from, bounds[phase] - from, CodebookSizes::of(books)});
    if (at + n == bounds[phase]) {
      result.report.sizes[phase - 1] = CodebookSizes::of(books);
      result.report.seconds[phase - 1] = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      result.report.cpu_seconds[phase - 1] = process_cpu_seconds() - cpu0;
    }
  }
  for (int phase = 1; phase <= 3; ++phase) {
    const size_t from = phase == 3 ? phase3_from : bounds[phase - 1];
    result.report.texels[phase - 1] = bounds[phase] - from;
    if (bounds[phase] == from) result.report.sizes[phase - 1] = CodebookSizes::of(books);
  }
  grown.add(encoder->stats());
  result.report.encoder = grown;
  if (frozen) {
    result.report.search = frozen->path();
    result.report.search_stats = frozen->stats();
  }
  return result;
}

}  // namespace btfvq
