#include <doctest/doctest.h>

#include <cmath>
#include <numeric>
#include <string>
#include <utility>
#include <vector>

#include "pipeline/codebook.h"
#include "pipeline/util/config.h"
#include "pipeline/encode/encoder.h"
#include <btfvq/error.h>
#include "support/synthetic_texels.h"

using namespace btfvq;
using btfvq::test::SyntheticMaterial;

namespace {

size_t total_entries(const Codebooks& k) {
  return k.p1.rows() + k.c.rows() + k.i1.rows() + k.i2.rows() + k.p2_index.rows() + k.m.rows() + k.p3_index.rows() +
         k.p4_index.rows();
}

// A texel scaled in the RGB sense: (Y-16, Cb-128, Cr-128) times s.
std::vector<float> rgb_scaled(const std::vector<float>& t, float s) {
  std::vector<float> out(t.size());
  const size_t n = t.size() / 3;
  for (size_t i = 0; i < t.size(); ++i) {
    const float o = i < n ? 16.0f : 128.0f;
    out[i] = o + s * (t[i] - o);
  }
  return out;
}

double reconstruction_dissimilarity(const Codebooks& k, Dynamic dyn, const SimilaritySettings& s,
                                    const std::vector<float>& texel, const P6Entry& e) {
  std::vector<float> recon(texel.size());
  reconstruct_texel(k, dyn, e.index, e.scale, recon.data());
  return texel_dissimilarity(s, dyn, k.grid, texel.data(), recon.data());
}

}  // namespace

TEST_CASE("reconstruct_texel follows the decode semantics on a hand-built code-book") {
  AngularGrid g{3, 2, 2, 1};
  Codebooks k(g);
  const float p1a[3] = {0.25f, 0.5f, 0.25f}, p1b[3] = {0.2f, 0.3f, 0.5f};
  k.p1.append(p1a);
  k.p1.append(p1b);
  const float c0[2] = {120, 130}, c1[2] = {140, 110};
  k.c.append(c0);
  k.c.append(c1);
  const uint32_t i1[3] = {0, 1, 0};
  k.i1.append(i1);
  const uint32_t i2[2] = {0, 0};
  k.i2.append(i2);
  const uint32_t p2[2] = {1, 0};
  const float p2s[2] = {300, 200};
  k.p2_index.append(p2);
  k.p2_scale.append(p2s);
  const uint32_t m[2] = {0, 0};
  k.m.append(m);
  const uint32_t p3[2] = {0, 0};
  const float p3s[2] = {1.0f, 0.5f};
  k.p3_index.append(p3);
  k.p3_scale.append(p3s);
  const uint32_t p4[1] = {0};
  const float p4s[1] = {2.0f};
  k.p4_index.append(p4);
  k.p4_scale.append(p4s);
  std::vector<float> out(3 * g.samples());
  reconstruct_texel(k, Dynamic::LDR, 0, 1.5f, out.data());
  const size_t n = g.samples();
  // theta_v 0, alpha 0, beta 2: Y = 300 * 0.5 = 150, scaled by 1.5 * 2 * 1 = 3 about 16.
  CHECK(out[g.index(0, 0, 0, 2)] == doctest::Approx(16 + 3 * (150 - 16)));
  // theta_v 1 (P3 scale 0.5): total 1.5; alpha 1, beta 1: Y = 200 * 0.5 = 100; Cb = 140, Cr = 110.
  CHECK(out[g.index(0, 1, 1, 1)] == doctest::Approx(16 + 1.5 * (100 - 16)));
  CHECK(out[n + g.index(0, 1, 1, 1)] == doctest::Approx(128 + 1.5 * (140 - 128)));
  CHECK(out[2 * n + g.index(0, 1, 1, 1)] == doctest::Approx(128 + 1.5 * (110 - 128)));
  // HDR: the scale multiplies Y and leaves the chroma.
  reconstruct_texel(k, Dynamic::HDR, 0, 1.5f, out.data());
  CHECK(out[g.index(0, 1, 1, 1)] == doctest::Approx(1.5 * 100));
  CHECK(out[n + g.index(0, 1, 1, 1)] == doctest::Approx(140));
  CHECK_THROWS_AS(reconstruct_texel(k, Dynamic::LDR, 1, 1.0f, out.data()), InputError);
}

TEST_CASE("growing phase: every texel is reconstructed within the P4 threshold; code-books are valid") {
  SyntheticMaterial mat(8, 8);
  Codebooks k(mat.grid);
  const SimilaritySettings s = SimilaritySettings::defaults();
  const Thresholds t = Thresholds::defaults();
  Encoder enc(k, Dynamic::LDR, t, s);
  for (uint32_t id = 0; id < 24; id += 1) {
    const auto texel = mat.texel(id * 5 % 64);
    const P6Entry e = enc.encode_growing(texel.data());
    CHECK(e.dissimilarity <= t.p4 + 1e-9);
    const double d = reconstruction_dissimilarity(k, Dynamic::LDR, s, texel, e);
    CHECK(d <= t.p4 + 2e-4);
    CHECK(d == doctest::Approx(e.dissimilarity).epsilon(1e-3).scale(1.0));
  }
  Database db{k, {}};
  CHECK_NOTHROW(db.validate());
  for (size_t r = 0; r < k.p1.rows(); ++r) {
    double sum = 0;
    for (size_t b = 0; b < k.p1.cols(); ++b) sum += k.p1.at(r, b);
    CHECK(sum == doctest::Approx(1.0).epsilon(1e-5));
  }
  CHECK(k.p4_index.rows() >= 1);
  CHECK(k.p4_index.rows() < 24);  // texels of one material class share entries
}

TEST_CASE("scaled copies of a texel reuse its entries with the scale in P6") {
  SyntheticMaterial mat(4, 4);
  Codebooks k(mat.grid);
  // The entry is built at a third of the shipped thresholds, so that it reconstructs the texel with
  // room to spare; scaled copies are then searched at the shipped ones.
  Encoder enc(k, Dynamic::LDR, Thresholds::defaults().relaxed(0.3), SimilaritySettings::defaults());
  const auto texel = mat.texel(5);
  const P6Entry first = enc.encode_growing(texel.data());
  enc.set_thresholds(Thresholds::defaults());
  const size_t before = total_entries(k);
  for (float s : {0.5f, 0.8f, 1.3f, 1.6f}) {
    const auto scaled = rgb_scaled(texel, s);
    const P6Entry e = enc.encode_growing(scaled.data());
    CHECK(e.index == first.index);
    CHECK(e.scale == doctest::Approx(s * first.scale).epsilon(1e-3));
    CHECK(total_entries(k) == before);
  }
}

TEST_CASE("code-books are append-only: encoding more texels never changes existing entries") {
  SyntheticMaterial mat(8, 8);
  Codebooks k(mat.grid);
  // Half the shipped thresholds: at the shipped ones this small material's later texels all match.
  Encoder enc(k, Dynamic::LDR, Thresholds::defaults().relaxed(0.5), SimilaritySettings::defaults());
  for (uint32_t id = 0; id < 6; ++id) enc.encode_growing(mat.texel(id * 11 % 64).data());
  const Codebooks snapshot = k;
  for (uint32_t id = 6; id < 16; ++id) enc.encode_growing(mat.texel(id * 11 % 64).data());
  CHECK(total_entries(k) > total_entries(snapshot));
  auto prefix = [](const auto& now, const auto& then) {
    REQUIRE(now.rows() >= then.rows());
    return std::equal(then.data().begin(), then.data().end(), now.data().begin());
  };
  CHECK(prefix(k.p1, snapshot.p1));
  CHECK(prefix(k.c, snapshot.c));
  CHECK(prefix(k.i1, snapshot.i1));
  CHECK(prefix(k.i2, snapshot.i2));
  CHECK(prefix(k.p2_index, snapshot.p2_index));
  CHECK(prefix(k.p2_scale, snapshot.p2_scale));
  CHECK(prefix(k.m, snapshot.m));
  CHECK(prefix(k.p3_index, snapshot.p3_index));
  CHECK(prefix(k.p3_scale, snapshot.p3_scale));
  CHECK(prefix(k.p4_index, snapshot.p4_index));
  CHECK(prefix(k.p4_scale, snapshot.p4_scale));
}

TEST_CASE("stricter thresholds give larger code-books and better reconstructions, looser the opposite") {
  SyntheticMaterial mat(8, 8);
  const SimilaritySettings s = SimilaritySettings::defaults();
  std::vector<std::vector<float>> texels;
  for (uint32_t id = 0; id < 16; ++id) texels.push_back(mat.texel(id * 13 % 64));
  auto run = [&](double factor, size_t* size) {
    Codebooks k(mat.grid);
    Encoder enc(k, Dynamic::LDR, Thresholds::defaults().relaxed(factor), s);
    std::vector<P6Entry> e;
    for (const auto& t : texels) e.push_back(enc.encode_growing(t.data()));
    double q = 0;  // quality measured after all insertions, with the final code-books
    for (size_t i = 0; i < texels.size(); ++i) q += reconstruction_dissimilarity(k, Dynamic::LDR, s, texels[i], e[i]);
    // The 2D and composite code-books: a loose 1D row accepted by its own threshold often misses in
    // its plane and is repaired with an exact row, so the leaves do not shrink monotonically.
    *size = k.p2_index.rows() + k.i2.rows() + k.m.rows() + k.p3_index.rows() + k.p4_index.rows();
    return q / double(texels.size());
  };
  size_t strict_size, normal_size, loose_size;
  const double strict = run(0.5, &strict_size), normal = run(1.0, &normal_size), loose = run(2.5, &loose_size);
  CHECK(strict_size > normal_size);
  CHECK(normal_size > loose_size);
  CHECK(strict < normal);
  CHECK(normal < loose);
}

TEST_CASE("pruning and proxy ordering choose exactly what the exhaustive search chooses") {
  SyntheticMaterial mat(8, 8);
  SimilaritySettings pruned = SimilaritySettings::defaults(), exhaustive = SimilaritySettings::defaults();
  // The shipped candidate_limit makes every search approximate; this is about the exact one.
  pruned.candidate_limit = exhaustive.candidate_limit = 0;
  exhaustive.pruning = false;
  Codebooks a(mat.grid), b(mat.grid);
  Encoder ea(a, Dynamic::LDR, Thresholds::defaults(), pruned), eb(b, Dynamic::LDR, Thresholds::defaults(), exhaustive);
  for (uint32_t id = 0; id < 12; ++id) {
    const auto t = mat.texel(id * 7 % 64);
    const P6Entry x = ea.encode_growing(t.data()), y = eb.encode_growing(t.data());
    CHECK(x.index == y.index);
    CHECK(x.scale == y.scale);
  }
  CHECK(a == b);  // every level made the same choices
  CHECK(ea.stats().pruned > 0);
  CHECK(eb.stats().pruned == 0);
  for (uint32_t id = 30; id < 40; ++id) {
    const auto t = mat.texel(id);
    const P6Entry x = ea.encode_frozen(t.data()), y = eb.encode_frozen(t.data());
    CHECK(x.index == y.index);
    CHECK(x.scale == y.scale);
    CHECK(x.dissimilarity == y.dissimilarity);
  }
}

TEST_CASE("frozen phase: best entry without insertion; empty code-books are an error") {
  SyntheticMaterial mat(8, 8);
  Codebooks k(mat.grid);
  Encoder enc(k, Dynamic::LDR, Thresholds::defaults(), SimilaritySettings::defaults());
  CHECK_THROWS_AS(enc.encode_frozen(mat.texel(0).data()), InputError);
  for (uint32_t id = 0; id < 8; ++id) enc.encode_growing(mat.texel(id * 9 % 64).data());
  const Codebooks before = k;
  const SimilaritySettings s = SimilaritySettings::defaults();
  for (uint32_t id = 40; id < 46; ++id) {
    const auto t = mat.texel(id);
    const P6Entry e = enc.encode_frozen(t.data());
    CHECK(e.index < k.p4_index.rows());
    // It is the best: no other P4 entry at its own best scale does better.
    const double d = reconstruction_dissimilarity(k, Dynamic::LDR, s, t, e);
    CHECK(d == doctest::Approx(e.dissimilarity).epsilon(1e-3).scale(1.0));
  }
  CHECK(k == before);
}

TEST_CASE("HDR and MSE encodings keep the guarantee too") {
  SUBCASE("HDR, SSIM") {
    SyntheticMaterial mat(4, 4, Dynamic::HDR);
    Codebooks k(mat.grid);
    const SimilaritySettings s = SimilaritySettings::defaults();
    Encoder enc(k, Dynamic::HDR, Thresholds::defaults(), s);
    for (uint32_t id = 0; id < 8; ++id) {
      const auto t = mat.texel(id);
      const P6Entry e = enc.encode_growing(t.data());
      CHECK(reconstruction_dissimilarity(k, Dynamic::HDR, s, t, e) <= Thresholds::defaults().p4 + 2e-4);
    }
  }
  SUBCASE("LDR, MSE") {
    SyntheticMaterial mat(4, 4);
    Codebooks k(mat.grid);
    SimilaritySettings s = SimilaritySettings::defaults();
    s.metric = Metric::MSE;
    const Thresholds t = Thresholds::from(ParameterDictionary::embedded_default("pipeline"), Metric::MSE);
    Encoder enc(k, Dynamic::LDR, t, s);
    for (uint32_t id = 0; id < 8; ++id) {
      const auto x = mat.texel(id);
      const P6Entry e = enc.encode_growing(x.data());
      CHECK(reconstruction_dissimilarity(k, Dynamic::LDR, s, x, e) <= t.p4 * 1.001);
    }
  }
}

TEST_CASE("thresholds come from the config; bad values are ConfigErrors naming the key") {
  auto d = ParameterDictionary::embedded_default("pipeline");
  const Thresholds t = Thresholds::from(d, Metric::SSIM);
  CHECK(t.p4 == doctest::Approx(0.075));
  auto mse = ParameterDictionary::embedded_default("pipeline");
  mse.merge(ParameterDictionary::parse(R"({"similarity": {"metric": "mse"}})", "override"));
  CHECK(Thresholds::from(mse).p4 == doctest::Approx(6.0));
  CHECK(Thresholds::from(d).p4 == doctest::Approx(0.075));
  CHECK(t.c == doctest::Approx(1.74));
  CHECK(t.p2 == doctest::Approx(0.058));
  const Thresholds r = t.relaxed(2.5);
  CHECK(r.p1 == doctest::Approx(2.5 * t.p1));
  CHECK(r.c == doctest::Approx(2.5 * t.c));
  for (const char* bad : {R"({"thresholds": {"ssim": {"p2": -0.1}}})", R"({"thresholds": {"ssim": {"m": 3}}})",
                          R"({"thresholds": {"mse": {"p4": "big"}}})", R"({"thresholds": {"ssim": {"c": -1}}})"}) {
    auto e = ParameterDictionary::embedded_default("pipeline");
    e.merge(ParameterDictionary::parse(bad, "override"));
    CHECK_THROWS_AS(Thresholds::from(e, Metric::SSIM), ConfigError);
  }
  CHECK_THROWS_AS(ParameterDictionary::parse(R"({"thresholds": {"ssim": {"p4": NaN}}})", "o"), ConfigError);
  CHECK_THROWS_AS(t.relaxed(-1), ConfigError);
}

TEST_CASE("MSE: the LAESA pivot bound and partial sums choose exactly what the exhaustive search chooses") {
  SyntheticMaterial mat(8, 8);
  SimilaritySettings pruned = SimilaritySettings::defaults(), exhaustive = SimilaritySettings::defaults();
  pruned.metric = exhaustive.metric = Metric::MSE;
  pruned.candidate_limit = exhaustive.candidate_limit = 0;  // the exact search (see above)
  exhaustive.pruning = false;
  const Thresholds t = Thresholds::from(ParameterDictionary::embedded_default("pipeline"), Metric::MSE).relaxed(0.3);
  Codebooks a(mat.grid), b(mat.grid);
  Encoder ea(a, Dynamic::LDR, t, pruned), eb(b, Dynamic::LDR, t, exhaustive);
  for (uint32_t id = 0; id < 16; ++id) {
    const auto x = mat.texel(id * 7 % 64);
    const P6Entry p = ea.encode_growing(x.data()), q = eb.encode_growing(x.data());
    CHECK(p.index == q.index);
    CHECK(p.scale == q.scale);
  }
  CHECK(a == b);
  REQUIRE(a.p4_index.rows() > 3);
  CHECK(ea.stats().laesa_skipped > 0);
  for (uint32_t id = 20; id < 40; ++id) {
    const auto x = mat.texel(id);
    const P6Entry p = ea.encode_frozen(x.data()), q = eb.encode_frozen(x.data());
    CHECK(p.index == q.index);
    CHECK(p.scale == q.scale);
  }
}

TEST_CASE("an approximate search (candidate_limit) evaluates fewer candidates and keeps the guarantee") {
  SyntheticMaterial mat(8, 8);
  SimilaritySettings exact = SimilaritySettings::defaults(), approx = SimilaritySettings::defaults();
  exact.candidate_limit = 0;
  approx.candidate_limit = 1;
  Codebooks a(mat.grid), b(mat.grid);
  Encoder ea(a, Dynamic::LDR, Thresholds::defaults(), exact), eb(b, Dynamic::LDR, Thresholds::defaults(), approx);
  for (uint32_t id = 0; id < 12; ++id) {
    const auto t = mat.texel(id * 7 % 64);
    ea.encode_growing(t.data());
    const P6Entry e = eb.encode_growing(t.data());
    CHECK(reconstruction_dissimilarity(b, Dynamic::LDR, approx, t, e) <= Thresholds::defaults().p4 + 2e-4);
  }
  // Entry counts are not ordered either way: the proxy-nearest candidates (the 1D code-books are
  // searched by ProxyIndex) often compose better than the SSIM-best ones, so fewer fallbacks insert.
  CHECK(eb.stats().comparisons < ea.stats().comparisons);
  CHECK_NOTHROW(Database{b, {}}.validate());
}

TEST_CASE("black texels (LDR 16/128/128, HDR zero) encode and reconstruct exactly") {
  AngularGrid g;
  const size_t n = g.samples();
  for (Dynamic dyn : {Dynamic::LDR, Dynamic::HDR}) {
    std::vector<float> black(3 * n);
    for (size_t i = 0; i < n; ++i) {
      black[i] = dyn == Dynamic::LDR ? 16.0f : 0.0f;
      black[n + i] = black[2 * n + i] = dyn == Dynamic::LDR ? 128.0f : 50.0f;
    }
    Codebooks k(g);
    Encoder enc(k, dyn, Thresholds::defaults(), SimilaritySettings::defaults());
    const P6Entry e = enc.encode_growing(black.data());
    std::vector<float> recon(3 * n);
    reconstruct_texel(k, dyn, e.index, e.scale, recon.data());
    for (size_t i = 0; i < 3 * n; i += 97) CHECK(recon[i] == doctest::Approx(black[i]).epsilon(1e-4));
    CHECK(enc.encode_frozen(black.data()).index == e.index);
  }
}

TEST_CASE("searches, parts searched ahead and composition checks on two threads grow exactly the code-books of one thread") {
  SyntheticMaterial mat(16, 16);
  mat.classes = 5;
  // The shipped approximate search, a tight one, every candidate; and the MSE metric.
  for (auto [metric, limit] : {std::pair{Metric::SSIM, 32}, {Metric::SSIM, 2}, {Metric::SSIM, 0}, {Metric::MSE, 32}}) {
    SimilaritySettings s = SimilaritySettings::defaults();
    s.metric = metric;
    s.candidate_limit = limit;
    Codebooks one(mat.grid), two(mat.grid);
    const Thresholds t = Thresholds::defaults(metric);
    Encoder a(one, Dynamic::LDR, t, s), b(two, Dynamic::LDR, t, s);
    b.set_threads(2);
    for (uint32_t id = 0; id < 256; id += 3) {
      const auto texel = mat.texel(id);
      const P6Entry ea = a.encode_growing(texel.data()), eb = b.encode_growing(texel.data());
      CHECK(ea.index == eb.index);
      CHECK(ea.scale == eb.scale);
      CHECK(ea.dissimilarity == eb.dissimilarity);
    }
    CHECK(one == two);
    CHECK(one.p4_index.rows() > 4);  // the searches had candidates to share
    CHECK(b.stats().comparisons > 0);
    // Parts were searched ahead, and some had to take entries inserted meanwhile into account.
    CHECK(b.stats().ahead > 0);
    CHECK(b.stats().ahead_extended > 0);
    // Rows of new planes were searched ahead, and some again after a row before them inserted.
    CHECK(b.stats().rows_ahead > 0);
    CHECK(b.stats().rows_redone > 0);
    MESSAGE(std::string(metric == Metric::SSIM ? "SSIM" : "MSE") << " limit " << limit << ": " << b.stats().ahead << " parts ahead, " << b.stats().ahead_extended
                     << " extended, " << b.stats().ahead_redone << " redone; " << b.stats().rows_ahead
                     << " rows ahead, " << b.stats().rows_redone << " redone");
    CHECK(a.stats().ahead == 0);
    CHECK(a.stats().rows_ahead == 0);
  }
}
