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
  CHECK(a == 41);
  CHECK(b == 164);
  phase_sizes(10, s, &a, &b);
  CHECK(a == 1);
  CHECK(b == 0);
}

TEST_CASE("three phases: growth only in phases 1 and 2, guarantee for grown texels, every texel indexed") {
  SyntheticMaterial mat(16, 16);
  const SimilaritySettings sim = SimilaritySettings::defaults();
  const Thresholds thr = Thresholds::defaults();
  ScheduleSettings sch = ScheduleSettings::defaults();
  sch.phase1_fraction = 0.03;
  sch.phase2_fraction = 0.06;
  sch.tile_texels = 16;
  Codebooks k(mat.grid);
  std::vector<ScheduleProgress> seen;
  const ScheduleResult r =
      run_schedule(k, Dynamic::LDR, 16, 16, mat.source(), thr, sim, sch, [&](const ScheduleProgress& p) { seen.push_back(p); });
  CHECK(r.report.texels[0] == 8);
  CHECK(r.report.texels[1] == 15);
  CHECK(r.report.texels[2] == 256 - 23);
  CHECK(r.report.sizes[1][CodebookId::P4] >= r.report.sizes[0][CodebookId::P4]);
  CHECK(r.report.sizes[2][CodebookId::P4] == r.report.sizes[1][CodebookId::P4]);
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

TEST_CASE("schedule settings come from the config; bad values are ConfigErrors") {
  auto d = ParameterDictionary::embedded_default("pipeline");
  const ScheduleSettings s = ScheduleSettings::from(d);
  CHECK(s.phase1_fraction == doctest::Approx(0.01));
  CHECK(s.phase2_fraction == doctest::Approx(0.04));
  CHECK(s.relax_factor == doctest::Approx(2.5));
  CHECK(s.tile_texels == 256);
  for (const char* bad : {R"({"schedule": {"phase1_fraction": -0.01}})", R"({"schedule": {"phase1_fraction": 0.7, "phase2_fraction": 0.5}})",
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
