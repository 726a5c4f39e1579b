// The batched phase-3 search (pipeline/encode/frozen_search.h, kernels/search.cl): the kernel agrees with
// its C++ reference, its brackets hold the exact scores, and every path picks the same entries; under
// MSE the closed form's brackets hold the exact squared errors and it picks the pruned search's entries.
#include <doctest/doctest.h>

#include "pipeline/encode/frozen_search.h"
#include "pipeline/runtime/opencl_runtime.h"
#include "support/synthetic_texels.h"

using namespace btfvq;
using btfvq::test::SyntheticMaterial;

namespace {

struct Grown {
  SyntheticMaterial mat{12, 12};
  Codebooks books{mat.grid};
  std::unique_ptr<Encoder> encoder;
  explicit Grown(Dynamic dyn = Dynamic::LDR, uint32_t texels = 40) : mat(12, 12, dyn), books(mat.grid) {
    encoder = std::make_unique<Encoder>(books, dyn, Thresholds::defaults(), SimilaritySettings::defaults());
    for (uint32_t id = 0; id < texels; ++id) encoder->encode_growing(mat.texel(id * 7 % 144).data());
  }
};

}  // namespace

TEST_CASE("the OpenCL kernel agrees with its C++ reference; brackets hold exact scores; abandonment is safe") {
  REQUIRE(ComputeDevice::get().uses_opencl());
  Grown g;
  REQUIRE(g.books.p4_index.rows() > 4);
  FrozenSearch gpu(*g.encoder, SearchPath::BatchedOpenCL, 2), cpu(*g.encoder, SearchPath::BatchedReference, 2);
  std::vector<FrozenQuery> queries;
  std::vector<uint32_t> candidates;
  const size_t slots = g.books.p4_index.rows();
  for (uint32_t t = 0; t < 16; ++t) {
    const auto texel = g.mat.texel(100 + t);
    queries.push_back(g.encoder->frozen_query(texel.data()));
    for (uint32_t e = 0; e < slots; ++e) candidates.push_back(e);
  }
  const std::vector<int> a = gpu.bins(queries, candidates, slots), b = cpu.bins(queries, candidates, slots);
  REQUIRE(a.size() == b.size());
  size_t same = 0, completed = 0, abandoned = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    // A value on a bin edge may round either way, and so may a value on the abandonment floor.
    if (a[i] >= 0 && b[i] >= 0) CHECK(std::abs(a[i] - b[i]) <= 1);
    same += (a[i] < 0) == (b[i] < 0) && std::abs(a[i] - b[i]) <= 1;
    completed += a[i] >= 0;
    abandoned += a[i] < 0;
  }
  CHECK(same >= a.size() * 95 / 100);
  CHECK(abandoned > a.size() / 4);  // abandonment does spare work on these code-books
  CHECK(completed >= 16);
  // A completed candidate's exact score (the pruned search restricted to it) lies in its bracket; an
  // abandoned one's lies below the best lower bound of the candidates completed before it.
  for (uint32_t t = 0; t < 16; ++t) {
    const auto texel = g.mat.texel(100 + t);
    CHECK(a[t * slots] >= 0);  // the first candidate always completes
    double best_lower = -1e300;
    for (uint32_t e = 0; e < slots; ++e) {
      const double score = 1.0 - g.encoder->encode_frozen_among(texel.data(), {e}, -1e300).dissimilarity;
      const int bin = a[t * slots + e];
      if (bin < 0) {
        CHECK(score < best_lower);
        continue;
      }
      double lo, hi;
      FrozenSearch::bracket(bin, &lo, &hi);
      CHECK(score >= lo);
      CHECK(score <= hi);
      best_lower = std::max(best_lower, lo);
    }
  }
}

TEST_CASE("batched (OpenCL and reference) and pruned phase 3 choose identical entries and scales") {
  REQUIRE(ComputeDevice::get().uses_opencl());
  for (Dynamic dyn : {Dynamic::LDR, Dynamic::HDR}) {
    Grown g(dyn, dyn == Dynamic::LDR ? 40 : 6);  // HDR code-books grow slowly: a few texels suffice
    const size_t values = 3 * g.mat.grid.samples();
    std::vector<float> texels;
    for (uint32_t t = 0; t < 24; ++t) {
      const auto x = g.mat.texel(t * 5 % 144);
      texels.insert(texels.end(), x.begin(), x.end());
    }
    std::vector<P6Entry> out[3];
    const SearchPath paths[3] = {SearchPath::Pruned, SearchPath::BatchedOpenCL, SearchPath::BatchedReference};
    for (int p = 0; p < 3; ++p) {
      FrozenSearch s(*g.encoder, paths[p], 2);
      out[p].resize(24);
      s.encode(texels.data(), 24, out[p].data());
      if (p > 0) CHECK(s.stats().settled < s.stats().scored);  // abandonment and brackets spare exact work
    }
    for (size_t i = 0; i < 24; ++i) {
      CHECK(out[1][i].index == out[0][i].index);
      CHECK(out[1][i].scale == out[0][i].scale);
      CHECK(out[2][i].index == out[0][i].index);
      CHECK(out[2][i].scale == out[0][i].scale);
      CHECK(out[0][i].index == g.encoder->encode_frozen(texels.data() + i * values).index);
    }
  }
}

TEST_CASE("under MSE the closed-form batch brackets the exact errors and picks the pruned search's entries") {
  Grown g;  // grown by SSIM, assigned by MSE: as run_schedule does with schedule.assign_metric "mse"
  SimilaritySettings sim = SimilaritySettings::defaults();
  sim.metric = Metric::MSE;
  Encoder mse(g.books, Dynamic::LDR, Thresholds::defaults(Metric::MSE), sim);
  REQUIRE(g.books.p4_index.rows() > 4);
  // Every batched path is the closed form under MSE: it needs no device.
  FrozenSearch batch(mse, SearchPath::BatchedOpenCL, 2), pruned(mse, SearchPath::Pruned, 2);
  CHECK(batch.path() == SearchPath::BatchedMSE);
  CHECK(pruned.path() == SearchPath::Pruned);
  CHECK(FrozenSearch(mse, SearchPath::BatchedReference, 1).path() == SearchPath::BatchedMSE);

  const size_t slots = g.books.p4_index.rows(), values = 3 * g.mat.grid.samples();
  std::vector<FrozenQuery> queries;
  std::vector<uint32_t> candidates;
  for (uint32_t t = 0; t < 16; ++t) {
    queries.push_back(mse.frozen_query(g.mat.texel(100 + t).data()));
    for (uint32_t e = 0; e < slots; ++e) candidates.push_back(e);
  }
  std::vector<double> error, margin;
  batch.squared_errors(queries, candidates, slots, &error, &margin);
  REQUIRE(error.size() == 16 * slots);
  for (uint32_t t = 0; t < 16; ++t)
    for (uint32_t e = 0; e < slots; ++e) {
      // The pruned search restricted to one candidate: its exact squared error.
      const double exact = mse.encode_frozen_among(g.mat.texel(100 + t).data(), {e}, -1e300).dissimilarity * double(values);
      const size_t k = t * slots + e;
      CHECK(exact >= error[k] - margin[k]);
      CHECK(exact <= error[k] + margin[k]);
    }

  std::vector<float> texels;
  for (uint32_t t = 0; t < 24; ++t) {
    const auto x = g.mat.texel(t * 5 % 144);
    texels.insert(texels.end(), x.begin(), x.end());
  }
  std::vector<P6Entry> a(24), b(24);
  batch.encode(texels.data(), 24, a.data());
  pruned.encode(texels.data(), 24, b.data());
  CHECK(batch.stats().settled < batch.stats().scored / 2);  // the brackets spare most exact comparisons
  for (size_t i = 0; i < 24; ++i) {
    CHECK(a[i].index == b[i].index);
    CHECK(a[i].scale == b[i].scale);
    CHECK(a[i].dissimilarity == b[i].dissimilarity);
  }

  // HDR chroma is compared unscaled, outside the closed form: the pruned search.
  Grown h(Dynamic::HDR, 6);
  Encoder hdr(h.books, Dynamic::HDR, Thresholds::defaults(Metric::MSE), sim);
  CHECK(FrozenSearch(hdr, SearchPath::BatchedOpenCL, 1).path() == SearchPath::Pruned);
  // The closed form is no SSIM search, and the SSIM batch has no squared errors.
  CHECK_THROWS_AS(FrozenSearch(*g.encoder, SearchPath::BatchedMSE, 1), InputError);
  CHECK_THROWS_AS(FrozenSearch(*g.encoder, SearchPath::BatchedReference, 1).squared_errors(queries, candidates, slots,
                                                                                          &error, &margin),
                  InputError);
  CHECK_THROWS_AS(batch.squared_errors(queries, {0, 1}, slots, &error, &margin), InputError);
}

TEST_CASE("bad batches are errors") {
  Grown g;
  FrozenSearch cpu(*g.encoder, SearchPath::BatchedReference, 1);
  std::vector<FrozenQuery> queries{g.encoder->frozen_query(g.mat.texel(3).data())};
  CHECK_THROWS_AS(cpu.bins(queries, {0, 1}, 1), InputError);
  CHECK_THROWS_AS(cpu.bins(queries, {100000}, 1), InputError);
  FrozenSearch pruned(*g.encoder, SearchPath::Pruned, 1);
  CHECK_THROWS_AS(pruned.bins(queries, {0}, 1), InputError);
}

TEST_CASE("grids the kernel's rows cannot hold use the pruned search; forcing the kernel on them is an error") {
  REQUIRE(ComputeDevice::get().uses_opencl());
  AngularGrid wide;
  wide.n_beta = 15;  // 15 samples + a border of 1 on each side > 16 lanes
  wide.n_theta_v = 3;
  wide.n_phi_v = 4;
  CHECK_FALSE(FrozenSearch::kernel_fits(wide, 1));
  CHECK(FrozenSearch::kernel_fits(wide, 0));
  CHECK(FrozenSearch::kernel_fits(AngularGrid{}, 1));
  CHECK(FrozenSearch::preferred(wide, SimilaritySettings::defaults()) == SearchPath::Pruned);
  CHECK(FrozenSearch::preferred(AngularGrid{}, SimilaritySettings::defaults()) == SearchPath::BatchedOpenCL);
  SimilaritySettings mse = SimilaritySettings::defaults();
  mse.metric = Metric::MSE;
  CHECK(FrozenSearch::preferred(AngularGrid{}, mse) == SearchPath::BatchedMSE);

  SyntheticMaterial mat(4, 4, Dynamic::LDR, wide);
  Codebooks books(mat.grid);
  Encoder encoder(books, Dynamic::LDR, Thresholds::defaults(), SimilaritySettings::defaults());
  for (uint32_t id = 0; id < 4; ++id) encoder.encode_growing(mat.texel(id).data());
  CHECK_THROWS_AS(FrozenSearch(encoder, SearchPath::BatchedOpenCL, 1), DeviceError);
  // The reference is scalar and holds any grid: it still picks the pruned search's entries.
  FrozenSearch reference(encoder, SearchPath::BatchedReference, 1);
  std::vector<float> texels;
  for (uint32_t id = 4; id < 8; ++id) {
    const auto x = mat.texel(id);
    texels.insert(texels.end(), x.begin(), x.end());
  }
  std::vector<P6Entry> out(4);
  reference.encode(texels.data(), 4, out.data());
  for (size_t i = 0; i < 4; ++i)
    CHECK(out[i].index == encoder.encode_frozen(texels.data() + i * 3 * mat.grid.samples()).index);
}
