#include <doctest/doctest.h>

#include <algorithm>
#include <atomic>
#include <set>
#include <vector>

#include "pipeline/util/config.h"
#include "pipeline/encode/encoder.h"
#include <btfvq/error.h>
#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/encode/schedule.h"
#include "support/synthetic_texels.h"

using namespace btfvq;
using btfvq::test::SyntheticMaterial;

TEST_CASE("Halton order is a permutation of the texels") {
  for (auto [w, h] : {std::pair{1, 1}, {7, 5}, {64, 64}, {3, 100}}) {
    const auto order = halton_order(w, h);
    REQUIRE(order.size() == size_t(w) * size_t(h));
    std::vector<uint32_t> sorted = order;
    std::sort(sorted.begin(), sorted.end());
    for (size_t i = 0; i < sorted.size(); ++i) CHECK(sorted[i] == i);
  }
  CHECK_THROWS_AS(halton_order(0, 4), InputError);
}

TEST_CASE("Halton order is well spread: its first 1% already covers every region") {
  const int w = 64, h = 64;
  const auto order = halton_order(w, h);
  // The first 41 texels (1% of 4096) fall into every one of the 4 x 4 blocks of 16 x 16 texels...
  std::set<int> blocks;
  for (size_t i = 0; i < 41; ++i) blocks.insert(int(order[i] % w) / 16 + 4 * (int(order[i] / w) / 16));
  CHECK(blocks.size() == 16);
  // ... and no two of the first 16 are neighbours (scan order would put them all on one row).
  for (size_t i = 0; i < 16; ++i)
    for (size_t j = i + 1; j < 16; ++j) {
      const int dx = std::abs(int(order[i] % w) - int(order[j] % w)), dy = std::abs(int(order[i] / w) - int(order[j] / w));
      CHECK(std::max(dx, dy) > 4);
    }
}

TEST_CASE("phase sizes follow the fractions, with at least one texel in phase 1") {
  ScheduleSettings s = ScheduleSettings::defaults();
  size_t a, b;
  phase_sizes(4096, s, &a, &b);
  CHECK(a == 16);   // round(0.004 x 4096)
  CHECK(b == 246);  // round(0.06 x 4096)
  phase_sizes(10, s, &a, &b);
  CHECK(a == 1);    // at least one
  CHECK(b == 1);
}

TEST_CASE("three phases: growth only in phases 1 and 2, guarantee for grown texels, every texel indexed") {
  SyntheticMaterial mat(16, 16);
  const SimilaritySettings sim = SimilaritySettings::defaults();
  const Thresholds thr = Thresholds::defaults();
  ScheduleSettings sch = ScheduleSettings::defaults();
  sch.phase1_fraction = 0.03;
  sch.phase2_fraction = 0.06;
  sch.tile_texels = 16;
  sch.refine.iterations = 0;  // the paper's three phases (test_refine covers the shipped refinement)
  Codebooks k(mat.grid);
  std::vector<ScheduleProgress> seen;
  const ScheduleResult r =
      run_schedule(k, Dynamic::LDR, 16, 16, mat.source(), thr, sim, sch, [&](const ScheduleProgress& p) { seen.push_back(p); });
  CHECK(r.report.texels[0] == 8);
  CHECK(r.report.texels[1] == 15);
  CHECK(r.report.texels[2] == 256 - 23);
  CHECK(r.report.sizes[1][CodebookId::P4] >= r.report.sizes[0][CodebookId::P4]);
  // Phase 3 grows nothing but the P4 entries it composes.
  CHECK(r.report.sizes[2][CodebookId::P4] == r.report.sizes[1][CodebookId::P4] + r.report.composed);
  CHECK(r.report.sizes[2][CodebookId::P1] == r.report.sizes[1][CodebookId::P1]);
  CHECK(r.report.sizes[2][CodebookId::P4] == k.p4_index.rows());
  Material m;
  m.name = "synthetic";
  m.width = m.height = 16;
  m.p6_index = r.p6_index;
  m.p6_scale = r.p6_scale;
  Database db{k, {m}};
  CHECK_NOTHROW(db.validate());
  for (int32_t i : r.p6_index) CHECK(i >= 0);
  // The texels of phases 1 and 2 are within the (relaxed) P4 threshold, measured independently.
  const auto order = halton_order(16, 16);
  std::vector<float> recon(3 * mat.grid.samples());
  for (size_t j = 0; j < 23; ++j) {
    const uint32_t id = order[j];
    const auto texel = mat.texel(id);
    reconstruct_texel(k, Dynamic::LDR, uint32_t(r.p6_index[id]), r.p6_scale[id], recon.data());
    const double d = texel_dissimilarity(sim, Dynamic::LDR, mat.grid, texel.data(), recon.data());
    CHECK(d <= (j < 8 ? thr.p4 : thr.relaxed(sch.relax_factor).p4) + 2e-4);
  }
  // Progress: phases in order, counts growing to each phase's total.
  REQUIRE(!seen.empty());
  CHECK(seen.front().phase == 1);
  CHECK(seen.back().phase == 3);
  CHECK(seen.back().done == seen.back().total);
  for (size_t i = 1; i < seen.size(); ++i)
    CHECK((seen[i].phase > seen[i - 1].phase || seen[i].done > seen[i - 1].done));
}

TEST_CASE("phase 3 gives the same result with one or two threads, and cancellation stops between tiles") {
  SyntheticMaterial mat(8, 8);
  ScheduleSettings sch = ScheduleSettings::defaults();
  sch.phase1_fraction = 0.05;
  sch.phase2_fraction = 0.05;
  sch.tile_texels = 8;
  Codebooks a(mat.grid), b(mat.grid);
  sch.threads = 1;
  const ScheduleResult r1 = run_schedule(a, Dynamic::LDR, 8, 8, mat.source(), Thresholds::defaults(), SimilaritySettings::defaults(), sch);
  sch.threads = 2;
  const ScheduleResult r2 = run_schedule(b, Dynamic::LDR, 8, 8, mat.source(), Thresholds::defaults(), SimilaritySettings::defaults(), sch);
  CHECK(r1.p6_index == r2.p6_index);
  CHECK(r1.p6_scale == r2.p6_scale);
  CHECK(a == b);

  Codebooks c(mat.grid);
  int tiles = 0;
  CHECK_THROWS_AS(run_schedule(c, Dynamic::LDR, 8, 8, mat.source(), Thresholds::defaults(), SimilaritySettings::defaults(), sch, {},
                               [&] { return ++tiles > 2; }),
                  CancelledError);
  CHECK(tiles == 3);
}

TEST_CASE("phase-3 composition: new P4 entries (and P3 entries with compose_p3), closer than the stored ones, the same on every path and thread count") {
  // Texels whose first phi_v groups come from one synthetic texel and the rest from another: a new
  // texel is then best made of the groups of stored ones, which is what composition does.
  SyntheticMaterial mat(16, 16);
  mat.classes = 4;
  const size_t samples = mat.grid.samples();
  auto spliced = [&](uint32_t id, float* out) {
    std::vector<float> other(3 * samples);
    mat.texel(id, out);
    mat.texel((id * 7 + 3) % 256, other.data());
    const size_t from = mat.grid.index(1 + int(id % 15), 0, 0, 0);
    for (int c = 0; c < 3; ++c)
      std::copy(other.begin() + c * samples + from, other.begin() + (c + 1) * samples, out + c * samples + from);
  };
  const TexelSource source = [&](const uint32_t* ids, size_t n, float* out) {
    for (size_t k = 0; k < n; ++k) spliced(ids[k], out + k * 3 * samples);
  };
  auto texel = [&](uint32_t id) {
    std::vector<float> v(3 * samples);
    spliced(id, v.data());
    return v;
  };
  const SimilaritySettings sim = SimilaritySettings::defaults();
  ScheduleSettings sch = ScheduleSettings::defaults();
  sch.phase1_fraction = 0.08;
  sch.phase2_fraction = 0.02;
  sch.tile_texels = 16;
  sch.compose_threshold = 0.0;  // every phase-3 texel tries
  // Phase 3 chooses and composes by schedule.assign_metric: SSIM (the batched kernel's paths) or
  // MSE (shipped); "closer" below is measured in that metric, independently of the encoder.
  Metric assign = Metric::MSE;
  SUBCASE("entries chosen by SSIM") { assign = Metric::SSIM; }
  SUBCASE("entries chosen by MSE") { assign = Metric::MSE; }
  CAPTURE(assign == Metric::SSIM);
  sch.assign_metric = assign;
  sch.assign_thresholds = Thresholds::defaults(assign);
  sch.compose_gain = assign == Metric::SSIM ? 0.009 : 2.0;
  SimilaritySettings measure = sim;
  measure.metric = assign;
  auto run = [&](int threads, const std::string& search, Codebooks& k) {
    ScheduleSettings s = sch;
    s.threads = threads;
    s.search = search;
    return run_schedule(k, Dynamic::LDR, 16, 16, source, Thresholds::defaults(), sim, s);
  };
  Codebooks base(mat.grid);
  const ScheduleResult r = run(1, "pruned", base);
  REQUIRE(r.report.composed > 0);
  // Nothing below P4 grows in phase 3; P4 grows by exactly the composed entries.
  for (CodebookId id : {CodebookId::P1, CodebookId::C, CodebookId::I1, CodebookId::I2, CodebookId::P2, CodebookId::M, CodebookId::P3})
    CHECK(r.report.sizes[2][id] == r.report.sizes[1][id]);
  CHECK(r.report.sizes[2][CodebookId::P4] == r.report.sizes[1][CodebookId::P4] + r.report.composed);

  // Without composition the same texels get the frozen P4 entries; with it, every phase-3 texel
  // that uses a composed entry is closer (measured independently of the encoder).
  Codebooks plain(mat.grid);
  ScheduleSettings off = sch;
  off.threads = 1;
  off.compose_threshold = assign == Metric::SSIM ? 2.0 : 1e6;  // never
  const ScheduleResult r0 = run_schedule(plain, Dynamic::LDR, 16, 16, source, Thresholds::defaults(), sim, off);
  CHECK(r0.report.composed == 0);
  CHECK(r0.report.sizes[2][CodebookId::P4] == r.report.sizes[1][CodebookId::P4]);
  const uint32_t first_composed = uint32_t(r.report.sizes[1][CodebookId::P4]);
  std::vector<float> recon(3 * mat.grid.samples());
  auto distance = [&](const Codebooks& k, const ScheduleResult& res, uint32_t id) {
    reconstruct_texel(k, Dynamic::LDR, uint32_t(res.p6_index[id]), res.p6_scale[id], recon.data());
    return texel_dissimilarity(measure, Dynamic::LDR, mat.grid, texel(id).data(), recon.data());
  };
  size_t using_composed = 0;
  double sum_with = 0, sum_without = 0;
  for (uint32_t id = 0; id < 256; ++id) {
    sum_with += distance(base, r, id);
    sum_without += distance(plain, r0, id);
    if (uint32_t(r.p6_index[id]) < first_composed) continue;
    ++using_composed;
    CHECK(distance(base, r, id) < distance(plain, r0, id));
  }
  CHECK(using_composed >= r.report.composed);
  CHECK(sum_with < sum_without);

  // Deterministic: the thread count and the search path (the batched kernel's C++ reference, and
  // OpenCL where a platform exists) give the same database.
  std::vector<std::pair<int, std::string>> variants = {{2, "pruned"}, {2, "batched-reference"}};
  if (ComputeDevice::get().uses_opencl()) variants.push_back({2, "batched"});
  for (const auto& [threads, search] : variants) {
    CAPTURE(search);
    Codebooks k(mat.grid);
    const ScheduleResult v = run(threads, search, k);
    CHECK(v.report.composed == r.report.composed);
    CHECK(v.p6_index == r.p6_index);
    CHECK(v.p6_scale == r.p6_scale);
    CHECK(k == base);
  }

  // compose_p3: groups whose best stored P3 entry misses the P3 threshold may get new P3 entries of
  // stored M entries. With a tight P3 threshold (most groups miss it), against the same run
  // without: the same growing phases, only P3 and P4 grow in phase 3, every new P3 row is used by a
  // new P4 row, the texels come out closer in sum, and thread count and search path do not matter.
  Thresholds tight = Thresholds::defaults();
  tight.p3 = 0.01;
  auto run_p3 = [&](bool compose_p3, int threads, const std::string& search, Codebooks& k, double share = 1) {
    ScheduleSettings s = sch;
    s.assign_thresholds.p3 = assign == Metric::SSIM ? 0.01 : 0.05;  // an MSE in squared 8-bit units
    s.compose_p3 = compose_p3;
    s.compose_p3_share = share;
    s.threads = threads;
    s.search = search;
    return run_schedule(k, Dynamic::LDR, 16, 16, source, tight, sim, s);
  };
  Codebooks without_p3(mat.grid), with_p3(mat.grid);
  const ScheduleResult r2 = run_p3(false, 1, "pruned", without_p3);
  const ScheduleResult r3 = run_p3(true, 1, "pruned", with_p3);
  CHECK(r3.report.sizes[1] == r2.report.sizes[1]);
  for (CodebookId id : {CodebookId::P1, CodebookId::C, CodebookId::I1, CodebookId::I2, CodebookId::P2, CodebookId::M})
    CHECK(r3.report.sizes[2][id] == r3.report.sizes[1][id]);
  CHECK(r2.report.sizes[2][CodebookId::P3] == r2.report.sizes[1][CodebookId::P3]);
  const size_t p3_grown = r3.report.sizes[1][CodebookId::P3];
  REQUIRE(r3.report.sizes[2][CodebookId::P3] > p3_grown);
  std::vector<char> used(with_p3.p3_index.rows(), 0);
  for (size_t e = r3.report.sizes[1][CodebookId::P4]; e < with_p3.p4_index.rows(); ++e)
    for (size_t p = 0; p < with_p3.p4_index.cols(); ++p) used[with_p3.p4_index.at(e, p)] = 1;
  for (size_t e = p3_grown; e < used.size(); ++e) CHECK(used[e]);
  double sum2 = 0, sum3 = 0;
  for (uint32_t id = 0; id < 256; ++id) {
    sum2 += distance(without_p3, r2, id);
    sum3 += distance(with_p3, r3, id);
  }
  CHECK(sum3 < sum2);
  MESSAGE("phase-3 P3 rows " << with_p3.p3_index.rows() - p3_grown << ", mean dissimilarity " << sum2 / 256 << " -> "
                             << sum3 / 256);
  // compose_p3_share: only the texels of an evenly spread share of the Halton order compose P3
  // entries. None: the run without; half: fewer new P3 rows than all, more than none.
  Codebooks none(mat.grid), half(mat.grid);
  run_p3(true, 1, "pruned", none, 0);
  CHECK(none == without_p3);
  run_p3(true, 1, "pruned", half, 0.5);
  MESSAGE("phase-3 P3 rows with half the texels composing them: " << half.p3_index.rows() - p3_grown);
  CHECK(half.p3_index.rows() > p3_grown);
  CHECK(half.p3_index.rows() < with_p3.p3_index.rows());
  for (const auto& [threads, search] : variants) {
    CAPTURE(search);
    Codebooks k(mat.grid);
    const ScheduleResult v = run_p3(true, threads, search, k);
    CHECK(v.p6_index == r3.p6_index);
    CHECK(v.p6_scale == r3.p6_scale);
    CHECK(k == with_p3);
  }
}

TEST_CASE("schedule settings come from the config; bad values are ConfigErrors") {
  auto d = ParameterDictionary::embedded_default("pipeline");
  const ScheduleSettings s = ScheduleSettings::from(d);
  CHECK(s.phase1_fraction == doctest::Approx(0.004));
  CHECK(s.phase2_fraction == doctest::Approx(0.06));
  CHECK(s.relax_factor == doctest::Approx(2.5));
  CHECK(s.tile_texels == 256);
  CHECK(s.assign_metric == Metric::MSE);
  CHECK(s.assign_thresholds.p4 == doctest::Approx(Thresholds::defaults(Metric::MSE).p4));
  for (const char* bad : {R"({"schedule": {"assign_metric": "l1"}})", R"({"schedule": {"compose_threshold": -1}})",
                          R"({"schedule": {"phase1_fraction": -0.01}})", R"({"schedule": {"phase1_fraction": 0.7, "phase2_fraction": 0.5}})",
                          R"({"schedule": {"relax_factor": 0.5}})", R"({"schedule": {"tile_texels": 0}})",
                          R"({"schedule": {"threads": 1.5}})"}) {
    auto e = ParameterDictionary::embedded_default("pipeline");
    e.merge(ParameterDictionary::parse(bad, "override"));
    CHECK_THROWS_AS(ScheduleSettings::from(e), ConfigError);
  }
  // A misspelled key in the section is reported by name.
  auto u = ParameterDictionary::embedded_default("pipeline");
  u.merge(ParameterDictionary::parse(R"({"schedule": {"tile_texel": 5}})", "override"));
  ScheduleSettings::from(u);
  try {
    u.check_unused();
    FAIL("expected ConfigError");
  } catch (const ConfigError& e) {
    CHECK(std::string(e.what()).find("schedule.tile_texel") != std::string::npos);
  }
}

TEST_CASE("schedule.search picks the phase-3 path; an unknown value is a ConfigError naming the key") {
  REQUIRE(ComputeDevice::get().uses_opencl());
  auto path = [](const std::string& value) {
    ParameterDictionary d = ParameterDictionary::embedded_default("pipeline");
    d.merge(ParameterDictionary(nlohmann::json{{"schedule", {{"search", value}}}}, "test"));
    return ScheduleSettings::from(d).search_path(AngularGrid{}, SimilaritySettings::defaults());
  };
  CHECK(path("auto") == SearchPath::BatchedOpenCL);
  CHECK(path("pruned") == SearchPath::Pruned);
  CHECK(path("batched") == SearchPath::BatchedOpenCL);
  CHECK(path("batched-reference") == SearchPath::BatchedReference);
  try {
    path("fastest");
    FAIL("an unknown search path was accepted");
  } catch (const ConfigError& e) {
    CHECK(std::string(e.what()).find("schedule.search") != std::string::npos);
  }
}
