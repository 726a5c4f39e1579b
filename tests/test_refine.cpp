#include <doctest/doctest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <future>
#include <numeric>
#include <vector>

#include "pipeline/encode/encoder.h"
#include "pipeline/encode/refine.h"
#include "pipeline/encode/schedule.h"
#include "pipeline/runtime/opencl_runtime.h"
#include <btfvq/error.h>
#include "support/synthetic_texels.h"

using namespace btfvq;
using btfvq::test::SyntheticMaterial;

namespace {

// Mean squared coding-space error of the assignment, from the decoder-side reconstruction: the
// independent measure of what refine_step reports.
double measured_mse(const Codebooks& k, const SyntheticMaterial& mat, const Assignment& as) {
  const size_t values = 3 * mat.grid.samples();
  std::vector<float> recon(values);
  double sum = 0;
  for (size_t i = 0; i < as.ids.size(); ++i) {
    const auto x = mat.texel(as.ids[i]);
    reconstruct_texel(k, mat.dyn, as.p4[i], as.scale[i], recon.data());
    for (size_t v = 0; v < values; ++v) sum += (double(recon[v]) - x[v]) * (double(recon[v]) - x[v]);
  }
  return sum / double(as.ids.size() * values);
}

ScheduleSettings growing_only() {
  ScheduleSettings s = ScheduleSettings::defaults();
  s.refine.iterations = 0;
  s.tile_texels = 32;
  return s;
}

Assignment assignment_of(const ScheduleResult& r) {
  Assignment as;
  for (uint32_t id = 0; id < r.p6_index.size(); ++id) {
    as.ids.push_back(id);
    as.p4.push_back(uint32_t(r.p6_index[id]));
    as.scale.push_back(r.p6_scale[id]);
  }
  return as;
}

// A 16 x 16 material grown with tight thresholds, so that the growth stores many rows close to
// each other: what the merges are for.
struct TightGrowth {
  SyntheticMaterial mat{16, 16};
  Codebooks grown;
  ScheduleResult r;
  TightGrowth() : mat(with_classes(4)), grown(mat.grid) {
    r = run_schedule(grown, Dynamic::LDR, 16, 16, mat.source(), Thresholds::defaults().relaxed(0.2),
                     SimilaritySettings::defaults(), growing_only());
  }
  static SyntheticMaterial with_classes(int n) {
    SyntheticMaterial m(16, 16);
    m.classes = n;
    return m;
  }
};

// The 16 x 16 material of a schedule result, re-assigned as `as` says, with its unreachable rows
// reclaimed: what a compression would write after the refinement.
Database reclaimed(const Codebooks& k, const ScheduleResult& r, const Assignment& as) {
  Material m;
  m.name = "m";
  m.width = m.height = 16;
  m.p6_index.assign(r.p6_index.begin(), r.p6_index.end());
  for (size_t i = 0; i < as.ids.size(); ++i) m.p6_index[as.ids[i]] = int32_t(as.p4[i]);
  m.p6_scale = as.scale;
  Database db{k, {m}};
  reclaim_unreachable(db);
  return db;
}

}  // namespace

TEST_CASE("a refinement step moves only the added rows, lowers the error, and reports the error the decoder makes") {
  for (Dynamic dyn : {Dynamic::LDR, Dynamic::HDR}) {
    CAPTURE(int(dyn));
    // Two materials into one set of code-books: the first one's rows count as published.
    SyntheticMaterial a(16, 16, dyn), b(16, 16, dyn);
    b.seed = 7;
    b.classes = 4;
    // Tighter than the shipped thresholds, so that the second material adds rows at every level.
    const Thresholds tight = Thresholds::defaults().relaxed(0.3);
    Codebooks k(a.grid);
    run_schedule(k, dyn, 16, 16, a.source(), tight, SimilaritySettings::defaults(), growing_only());
    const Codebooks before_b = k;
    const CodebookSizes first = CodebookSizes::of(k);
    const ScheduleResult r = run_schedule(k, dyn, 16, 16, b.source(), tight, SimilaritySettings::defaults(), growing_only());
    REQUIRE(CodebookSizes::of(k)[CodebookId::P1] > first[CodebookId::P1]);
    const Codebooks grown = k;

    Assignment as = assignment_of(r);
    const double mse0 = measured_mse(k, b, as);
    const RefineStep step = refine_step(k, first, dyn, as, b.source(), 32);
    CHECK(step.mse_before == doctest::Approx(mse0).epsilon(1e-6));
    CHECK(step.mse_after == doctest::Approx(measured_mse(k, b, as)).epsilon(1e-4));
    // (HDR gains little on this material: the bound there is only that the error falls.)
    CHECK(step.mse_after < (dyn == Dynamic::LDR ? 0.98 : 1.0) * step.mse_before);

    // Rows of the first material, and the shape of every table, are as they were.
    CHECK(CodebookSizes::of(k) == CodebookSizes::of(grown));
    auto same_prefix = [](const auto& now, const auto& then, size_t rows) {
      return std::equal(then.data().begin(), then.data().begin() + ptrdiff_t(rows * then.cols()), now.data().begin());
    };
    CHECK(same_prefix(k.p1, before_b.p1, first[CodebookId::P1]));
    CHECK(same_prefix(k.c, before_b.c, first[CodebookId::C]));
    CHECK(same_prefix(k.i1, before_b.i1, first[CodebookId::I1]));
    CHECK(same_prefix(k.p2_scale, before_b.p2_scale, first[CodebookId::P2]));
    CHECK(same_prefix(k.p3_scale, before_b.p3_scale, first[CodebookId::P3]));
    CHECK(same_prefix(k.p4_scale, before_b.p4_scale, first[CodebookId::P4]));
    CHECK(!(k.p1 == grown.p1));  // and the added ones moved
    // P1 rows stay densities: non-negative, summing to 1 where they were moved.
    for (size_t e = first[CodebookId::P1]; e < k.p1.rows(); ++e) {
      double sum = 0;
      for (size_t c = 0; c < k.p1.cols(); ++c) {
        CHECK(k.p1.at(e, c) >= 0.0f);
        sum += k.p1.at(e, c);
      }
      CHECK(sum == doctest::Approx(1.0).epsilon(1e-4));
    }
    CHECK_NOTHROW((Database{k, {}}.validate()));

    // A second step from where the first left off starts at its error.
    const RefineStep again = refine_step(k, first, dyn, as, b.source(), 7);
    CHECK(again.mse_before == doctest::Approx(step.mse_after).epsilon(1e-4));
    CHECK(again.mse_after <= again.mse_before);
  }
}

TEST_CASE("merging: near rows become one, more with a larger radius, and the error reported is still the decoder's") {
  const TightGrowth g;
  const RefineMerge shipped = ScheduleSettings::defaults().refine.merge;
  REQUIRE(shipped.p1 > 0);
  REQUIRE(shipped.p2 > 0);
  size_t last_p1 = SIZE_MAX, last_p2 = SIZE_MAX;
  double last_mse = 0;
  for (double f : {0.0, 3.0, 8.0}) {
    CAPTURE(f);
    Codebooks k = g.grown;
    Assignment as = assignment_of(g.r);
    const RefineStep step = refine_step(k, {}, Dynamic::LDR, as, g.mat.source(), 32, {shipped.p1 * f, shipped.p2 * f});
    CHECK(step.mse_after == doctest::Approx(measured_mse(k, g.mat, as)).epsilon(1e-4));
    const Database db = reclaimed(k, g.r, as);
    CHECK_NOTHROW(db.validate());
    const size_t p1 = db.codebooks.p1.rows(), p2 = db.codebooks.p2_index.rows();
    if (f == 0) {
      CHECK(step.mse_after < step.mse_before);
    } else {
      CHECK(p1 < last_p1);  // every step of the radius merges more
      CHECK(p2 < last_p2);
      CHECK(step.mse_after >= last_mse);  // and costs more
    }
    last_p1 = p1;
    last_p2 = p2;
    last_mse = step.mse_after;
  }
}

TEST_CASE("merging within a budget: the cheapest merges are kept, fewer as the budget shrinks, none at 0 but exact copies") {
  const TightGrowth g;
  const SyntheticMaterial& mat = g.mat;
  const Codebooks& grown = g.grown;
  const ScheduleResult& r = g.r;
  const RefineMerge shipped = ScheduleSettings::defaults().refine.merge;
  REQUIRE(shipped.budget > 0);
  REQUIRE(shipped.budget < 1);  // the shipped budget binds somewhere
  auto rows_after = [&](double budget, RefineStep* step) {
    Codebooks k = grown;
    Assignment as = assignment_of(r);
    RefineMerge m{shipped.p1 * 8, shipped.p2 * 8, shipped.i1 * 8, shipped.i2 * 8};
    m.budget = budget;
    *step = refine_step(k, {}, Dynamic::LDR, as, mat.source(), 32, m);
    const Database db = reclaimed(k, r, as);
    REQUIRE_NOTHROW(db.validate());
    return db.codebooks.p1.rows() + db.codebooks.p2_index.rows() + db.codebooks.i1.rows() + db.codebooks.i2.rows();
  };
  RefineStep none, zero, some, all;
  Codebooks k = grown;
  Assignment as = assignment_of(r);
  none = refine_step(k, {}, Dynamic::LDR, as, mat.source(), 32, {});
  const size_t unmerged = rows_after(0.0, &zero), partly = rows_after(0.02, &some), merged = rows_after(1e300, &all);
  CAPTURE(unmerged);
  CAPTURE(partly);
  CAPTURE(merged);
  CHECK(merged < partly);
  CHECK(partly < unmerged);
  CHECK(zero.mse_after == doctest::Approx(none.mse_after).epsilon(1e-6));  // a budget of 0 merges nothing that costs
  CHECK(zero.mse_after <= some.mse_after);
  CHECK(some.mse_after <= all.mse_after);
  // What the budget allows is a bound on the estimate, and the refits after the merges only lower the
  // error: the partly merged step ends within the budget of the unmerged one (plus the refits' slack).
  CHECK(some.mse_after <= zero.mse_after + 4 * 0.02 * some.mse_before);
}

// The merges as docs/encoder.md defines them, one row after the other against every leader:
// the independent reference of merge_leaders.
std::vector<uint32_t> exhaustive_leaders(const std::vector<float>& rows, size_t dim, const std::vector<double>& w,
                                         double radius, double budget) {
  const size_t n = w.size();
  std::vector<uint32_t> leader(n), order, leaders;
  std::iota(leader.begin(), leader.end(), 0u);
  double mean_weight = 0;
  for (uint32_t r = 0; r < n; ++r)
    if (w[r] > 0) {
      order.push_back(r);
      mean_weight += w[r];
    }
  mean_weight /= double(order.size());
  std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return w[a] > w[b]; });
  std::vector<std::pair<double, uint32_t>> merges;
  for (uint32_t r : order) {
    double best = radius * radius * mean_weight / w[r];
    int64_t chosen = -1;
    for (uint32_t l : leaders) {  // in the order they became leaders: the first of equals wins
      double d = 0;
      for (size_t v = 0; v < dim; ++v) d += double(rows[r * dim + v] - rows[l * dim + v]) * (rows[r * dim + v] - rows[l * dim + v]);
      if (d < best || (d == best && chosen < 0)) {
        best = d;
        chosen = l;
      }
    }
    if (chosen < 0) {
      leaders.push_back(r);
    } else {
      leader[r] = uint32_t(chosen);
      merges.emplace_back(w[r] * best, r);
    }
  }
  std::sort(merges.begin(), merges.end());
  double spent = 0;
  for (const auto& [cost, r] : merges)
    if ((spent += cost) > budget) leader[r] = r;
  return leader;
}

TEST_CASE("merge_leaders is the row-by-row search over every leader, on any thread count") {
  // 2,000 rows of 12 values around 40 centres (several batches of rows), with exact copies, rows
  // of weight 0 and weights spread over three decades.
  const size_t n = 2000, dim = 12;
  uint64_t state = 12345;
  auto uniform = [&] {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return double(state >> 11) / double(1ull << 53);
  };
  std::vector<float> centres(40 * dim);
  for (float& c : centres) c = float(uniform() * 10);
  std::vector<float> rows(n * dim);
  std::vector<double> w(n);
  for (size_t r = 0; r < n; ++r) {
    const size_t c = size_t(uniform() * 40);
    for (size_t v = 0; v < dim; ++v) rows[r * dim + v] = centres[c * dim + v] + float(uniform() - 0.5);
    if (r % 97 == 5) std::copy_n(&rows[(r - 5) * dim], dim, &rows[r * dim]);
    w[r] = r % 53 == 0 ? 0.0 : std::pow(10.0, 3 * uniform());
  }
  for (double radius : {0.05, 0.3, 1.0}) {
    for (double budget : {1e300, 50.0, 0.0}) {
      CAPTURE(radius);
      CAPTURE(budget);
      const std::vector<uint32_t> expected = exhaustive_leaders(rows, dim, w, radius, budget);
      const size_t merged = n - size_t(std::count_if(expected.begin(), expected.end(), [i = 0u](uint32_t l) mutable { return l == i++; }));
      if (budget > 1) CHECK(merged > 0);  // the case exercises merges
      CHECK(merge_leaders(rows, dim, w, radius, budget, 1) == expected);
      CHECK(merge_leaders(rows, dim, w, radius, budget, 2) == expected);
    }
  }
  CHECK_THROWS_AS(merge_leaders(rows, dim + 1, w, 0.3, 1e300), InputError);

  // Degenerate rows: all on one line through the origin (the spread has rank 1, so only one of the
  // search's directions is real), and only two rows.
  std::vector<float> line(600 * dim);
  std::vector<double> line_w(600);
  for (size_t r = 0; r < 600; ++r) {
    const float t = float(int(uniform() * 200)) * 0.01f;  // copies among them too
    for (size_t v = 0; v < dim; ++v) line[r * dim + v] = t * float(v % 3 + 1);
    line_w[r] = 1 + uniform();
  }
  const std::vector<float> two(line.begin(), line.begin() + ptrdiff_t(2 * dim));
  const std::vector<double> two_w(line_w.begin(), line_w.begin() + 2);
  for (double radius : {0.01, 0.1}) {
    CAPTURE(radius);
    CHECK(merge_leaders(line, dim, line_w, radius, 1e300, 2) == exhaustive_leaders(line, dim, line_w, radius, 1e300));
    CHECK(merge_leaders(two, dim, two_w, radius, 1e300, 2) == exhaustive_leaders(two, dim, two_w, radius, 1e300));
  }
}

TEST_CASE("assigning each tile inside the first pass is assigning every texel before the step") {
  const TightGrowth g;
  Codebooks grown = g.grown;  // what the assignments search
  const Encoder before(grown, Dynamic::LDR, Thresholds::defaults(), SimilaritySettings::defaults());
  // Separately: every texel assigned with the grown code-books, then the step.
  Codebooks apart = g.grown;
  Assignment as_apart = assignment_of(g.r);
  for (size_t i = 0; i < as_apart.ids.size(); ++i) {
    const P6Entry e = before.encode_frozen(g.mat.texel(as_apart.ids[i]).data());
    as_apart.p4[i] = e.index;
    as_apart.scale[i] = e.scale;
  }
  const RefineMerge merge = ScheduleSettings::defaults().refine.merge;
  const RefineStep step_apart = refine_step(apart, {}, Dynamic::LDR, as_apart, g.mat.source(), 32, merge);
  // In the pass: the assignment starts out wrong (entry 0, scale 1 everywhere) and tiles of 7.
  Codebooks fused = g.grown;
  Assignment as_fused = assignment_of(g.r);
  std::fill(as_fused.p4.begin(), as_fused.p4.end(), 0u);
  std::fill(as_fused.scale.begin(), as_fused.scale.end(), 1.0f);
  size_t tiles = 0;
  const size_t values = 3 * g.mat.grid.samples();
  const RefineStep step_fused = refine_step(fused, {}, Dynamic::LDR, as_fused, g.mat.source(), 7, merge, 0,
                                            [&](const float* x, size_t n, uint32_t* p4, float* scale) {
                                              ++tiles;
                                              for (size_t i = 0; i < n; ++i) {
                                                const P6Entry e = before.encode_frozen(x + i * values);
                                                p4[i] = e.index;
                                                scale[i] = e.scale;
                                              }
                                            });
  CHECK(tiles == (as_fused.ids.size() + 6) / 7);
  CHECK(step_fused.mse_before == step_apart.mse_before);
  CHECK(step_fused.mse_after == step_apart.mse_after);
  CHECK(as_fused.p4 == as_apart.p4);
  CHECK(as_fused.scale == as_apart.scale);
  CHECK(fused == apart);
  // An entry past the end of P4 from the assignment is refused as one in the assignment is.
  Codebooks k = g.grown;
  Assignment as = assignment_of(g.r);
  const uint32_t past = uint32_t(k.p4_index.rows());
  CHECK_THROWS_AS(refine_step(k, {}, Dynamic::LDR, as, g.mat.source(), 32, {}, 0,
                              [&](const float*, size_t n, uint32_t* p4, float*) { std::fill_n(p4, n, past); }),
                  InputError);
}

TEST_CASE("refine_step rejects an assignment that does not fit the code-books") {
  SyntheticMaterial mat(4, 4);
  Codebooks k(mat.grid);
  Assignment as{{0, 1}, {0}, {1.0f, 1.0f}};
  CHECK_THROWS_AS(refine_step(k, {}, Dynamic::LDR, as, mat.source(), 4), InputError);
  as.p4 = {0, 0};  // P4 is empty
  CHECK_THROWS_AS(refine_step(k, {}, Dynamic::LDR, as, mat.source(), 4), InputError);
}

TEST_CASE("the shipped schedule refines: phase 3 assigns every texel, closer than without, the same on every thread count and path") {
  SyntheticMaterial mat(16, 16);
  mat.classes = 4;
  const ScheduleSettings shipped = ScheduleSettings::defaults();
  REQUIRE(shipped.refine.iterations > 0);
  ScheduleSettings sch = shipped;
  sch.tile_texels = 32;
  auto run = [&](Codebooks& k, const ScheduleSettings& s) {
    return run_schedule(k, Dynamic::LDR, 16, 16, mat.source(), Thresholds::defaults(), SimilaritySettings::defaults(), s);
  };
  Codebooks refined(mat.grid), plain(mat.grid);
  std::vector<ScheduleProgress> seen;
  const ScheduleResult r = run_schedule(refined, Dynamic::LDR, 16, 16, mat.source(), Thresholds::defaults(),
                                        SimilaritySettings::defaults(), sch,
                                        [&](const ScheduleProgress& p) { seen.push_back(p); });
  ScheduleSettings off = sch;
  off.refine.iterations = 0;
  const ScheduleResult r0 = run(plain, off);

  CHECK(r.report.texels[2] == 256);  // phase 3 re-assigns the grown texels too
  CHECK(r0.report.texels[2] == 256 - r0.report.texels[0] - r0.report.texels[1]);
  REQUIRE(!r.report.refine.empty());
  CHECK(r.report.refine_texels >= r.report.texels[0] + r.report.texels[1]);
  for (const RefineStep& s : r.report.refine) CHECK(s.mse_after < s.mse_before);
  CHECK(std::any_of(seen.begin(), seen.end(), [](const ScheduleProgress& p) { return p.refining; }));
  // The same growth, then the refinement: the whole material is closer.
  CHECK(r.report.sizes[1] == r0.report.sizes[1]);
  const double with = measured_mse(refined, mat, assignment_of(r)), without = measured_mse(plain, mat, assignment_of(r0));
  CHECK(with < 0.95 * without);

  std::vector<std::pair<int, std::string>> variants = {{1, "pruned"}, {2, "batched-reference"}};
  if (ComputeDevice::get().uses_opencl()) variants.push_back({2, "batched"});
  for (const auto& [threads, search] : variants) {
    CAPTURE(search);
    ScheduleSettings s = sch;
    s.threads = threads;
    s.search = search;
    Codebooks k(mat.grid);
    const ScheduleResult v = run(k, s);
    CHECK(k == refined);
    CHECK(v.p6_index == r.p6_index);
    CHECK(v.p6_scale == r.p6_scale);
  }
}

TEST_CASE("tiles arrive in order with their own texels, one source call at a time; a source error reaches the caller") {
  // A source whose values name the texel and position, and that notes overlapping calls.
  std::atomic<int> inside{0};
  bool overlapped = false;
  std::vector<size_t> calls;
  const TexelSource source = [&](const uint32_t* ids, size_t n, float* out) {
    overlapped = overlapped || inside.fetch_add(1) > 0;
    calls.push_back(n);
    for (size_t i = 0; i < n; ++i)
      for (size_t v = 0; v < 3; ++v) out[i * 3 + v] = float(ids[i] * 10 + v);
    inside.fetch_sub(1);
  };
  std::vector<uint32_t> ids(23);
  for (size_t i = 0; i < ids.size(); ++i) ids[i] = uint32_t(100 + 7 * i);
  std::vector<size_t> seen;
  for_each_tile(ids.data(), ids.size(), source, 5, 3, [&](size_t at, size_t n, const float* x) {
    CHECK(at == seen.size());
    for (size_t i = 0; i < n; ++i) {
      seen.push_back(at + i);
      for (size_t v = 0; v < 3; ++v) CHECK(x[i * 3 + v] == float(ids[at + i] * 10 + v));
    }
  });
  CHECK(seen.size() == ids.size());
  CHECK(calls == std::vector<size_t>{5, 5, 5, 5, 3});
  CHECK_FALSE(overlapped);

  // A taken tile stays valid while the next one is fetched.
  TilePrefetch prefetch(source, 3);
  prefetch.fetch(ids.data(), 4);
  const float* first = prefetch.take();
  prefetch.fetch(ids.data() + 4, 4);
  CHECK(first[0] == float(ids[0] * 10));
  const float* second = prefetch.take();
  CHECK(second[0] == float(ids[4] * 10));
  CHECK(first[3 * 3] == float(ids[3] * 10));
  CHECK_THROWS_AS(prefetch.take(), std::future_error);  // nothing fetched

  const TexelSource broken = [](const uint32_t*, size_t, float*) { throw InputError("damaged sample"); };
  size_t visited = 0;
  CHECK_THROWS_AS(for_each_tile(ids.data(), ids.size(), broken, 5, 3, [&](size_t, size_t, const float*) { ++visited; }),
                  InputError);
  CHECK(visited == 0);
  TilePrefetch again(broken, 3);
  again.fetch(ids.data(), 2);
  CHECK_THROWS_AS(again.take(), InputError);
}
