// The blocked proxy-signature table gives, bit for bit, the distance of the one-entry formula the
// encoder ordered its candidates by before the table existed (so databases did not change).
#include <doctest/doctest.h>

#include <cmath>
#include <cstring>
#include <random>
#include <vector>

#include <algorithm>

#include "pipeline/encode/signature_table.h"

using namespace btfvq;

namespace {

// The formula as the encoder had it inline: three sums in one loop, the best scale clamped at 0.
float reference_distance(const float* q, const float* y, int n) {
  double qy = 0, yy = 0, qq = 0;
  for (int i = 0; i < n; ++i) {
    qy += double(q[i]) * y[i];
    yy += double(y[i]) * y[i];
    qq += double(q[i]) * q[i];
  }
  const double s = yy > 0 ? std::max(0.0, qy / yy) : 0.0;
  return float(qq - 2 * s * qy + s * s * yy);
}

bool same_bits(float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; }

}  // namespace

TEST_CASE("scaled distances of the blocked table equal the one-entry formula bitwise") {
  std::mt19937 rng(11);
  std::normal_distribution<float> value(0.0f, 30.0f);
  for (int width : {1, 21, 33, 336}) {
    SignatureTable table(width);
    std::vector<std::vector<float>> rows;
    for (int e = 0; e < 77; ++e) {  // not a multiple of the block width
      std::vector<float> r(static_cast<size_t>(width));
      for (float& v : r) v = value(rng);
      if (e == 5) std::fill(r.begin(), r.end(), 0.0f);  // an all-zero entry: scale 0
      table.append(r.data());
      rows.push_back(r);
    }
    REQUIRE(table.size() == 77);
    std::vector<float> q(static_cast<size_t>(width));
    for (float& v : q) v = value(rng);
    for (auto [first, last] : {std::pair<size_t, size_t>{0, 77}, {3, 9}, {8, 16}, {70, 77}, {76, 200}}) {
      std::vector<float> out(last - first, -1.0f);
      table.scaled_distances(q.data(), first, last, out.data());
      for (size_t e = first; e < std::min<size_t>(last, 77); ++e) {
        const float want = reference_distance(q.data(), rows[e].data(), width);
        CHECK(same_bits(out[e - first], want));
        CHECK(same_bits(scaled_distance(q.data(), rows[e].data(), width), want));
        CHECK(std::memcmp(table.row(e), rows[e].data(), sizeof(float) * size_t(width)) == 0);
      }
    }
  }
}

TEST_CASE("a scaled copy of an entry is at distance 0 from it, an unrelated one is not") {
  SignatureTable table(4);
  const float a[4] = {1, 2, 3, 4}, b[4] = {4, -3, 2, -1};
  table.append(a);
  table.append(b);
  const float q[4] = {2.5f, 5, 7.5f, 10};
  float d[2];
  table.scaled_distances(q, 0, 2, d);
  CHECK(d[0] == doctest::Approx(0.0).epsilon(1e-6));
  CHECK(d[1] > 100.0f);  // best scale of b is 0 (negative correlation): the whole |q|^2 = 187.5
  CHECK(d[1] == doctest::Approx(187.5));
}

TEST_CASE("nearest() returns the k first of all entries sorted by (distance, index)") {
  std::mt19937 rng(5);
  std::normal_distribution<float> value(0.0f, 1.0f);
  const int np = 16, nt = 7;
  const int width = 3 * np * nt;  // a P4 signature
  SignatureTable table(width);
  std::vector<std::vector<float>> rows;
  // Entries clustered like code-book entries (a few shapes, each at many scales and with noise),
  // plus exact duplicates and scaled copies, so that ties and near-ties occur.
  std::vector<std::vector<float>> shapes(6, std::vector<float>(size_t(width)));
  for (auto& s : shapes)
    for (float& v : s) v = 20.0f + 5.0f * value(rng);
  for (int e = 0; e < 1500; ++e) {
    std::vector<float> r = shapes[size_t(e) % shapes.size()];
    const float scale = 0.5f + 0.01f * float(e % 97);
    for (float& v : r) v = v * scale + 0.3f * value(rng);
    if (e % 50 == 7) r = rows[size_t(e - 7)];  // a duplicate of an earlier entry: equal distance
    table.append(r.data());
    rows.push_back(r);
  }
  for (int trial = 0; trial < 40; ++trial) {
    std::vector<float> q = rows[size_t(trial * 37) % rows.size()];
    for (float& v : q) v = v * 1.7f + (trial % 3) * 0.2f * value(rng);
    std::vector<std::pair<float, uint32_t>> all;
    for (uint32_t e = 0; e < rows.size(); ++e) all.push_back({reference_distance(q.data(), rows[e].data(), width), e});
    std::sort(all.begin(), all.end());
    for (size_t k : {size_t(1), size_t(16), size_t(32)}) {
      std::vector<uint32_t> got, got2;
      table.nearest(q.data(), k, got);
      table.nearest(q.data(), k, got2, 2);  // 1500 x 336 values: the scan is split over two threads
      REQUIRE(got.size() == k);
      CHECK(got2 == got);
      std::vector<uint32_t> want;
      for (size_t i = 0; i < k; ++i) want.push_back(all[i].second);
      CHECK(got == want);
    }
  }
  std::vector<uint32_t> few;
  table.nearest(rows[0].data(), 5000, few);  // more than there are: all of them, sorted
  CHECK(few.size() == rows.size());
  CHECK(few[0] == 0);
}

TEST_CASE("nearest_many() of several queries at once, and extend() after appends, equal nearest()") {
  std::mt19937 rng(8);
  std::normal_distribution<float> value(0.0f, 1.0f);
  const int width = 33;  // an M signature: 3 channels x 11 rows
  SignatureTable table(width);
  std::vector<std::vector<float>> shapes(5, std::vector<float>(size_t(width)));
  for (auto& s : shapes)
    for (float& v : s) v = 10.0f + 4.0f * value(rng);
  auto add = [&](int e) {
    std::vector<float> r = shapes[size_t(e) % shapes.size()];
    for (float& v : r) v = v * (0.6f + 0.02f * float(e % 31)) + 0.2f * value(rng);
    if (e % 40 == 3 && e > 40) {  // a duplicate: a tie broken by the index
      std::vector<float> d(table.row(size_t(e - 40)), table.row(size_t(e - 40)) + width);
      r = d;
    }
    table.append(r.data());
  };
  for (int e = 0; e < 2300; ++e) add(e);  // 2300 x 33 x 7 values: the queries spread over threads below
  std::vector<std::vector<float>> queries(7, std::vector<float>(size_t(width)));
  for (size_t q = 0; q < queries.size(); ++q)
    for (int i = 0; i < width; ++i) queries[q][size_t(i)] = table.row(q * 101)[i] * 1.3f + 0.1f * value(rng);
  std::vector<const float*> qs;
  for (auto& q : queries) qs.push_back(q.data());
  for (size_t threads : {size_t(1), size_t(2)}) {
    for (size_t first : {size_t(0), size_t(5), size_t(2299), size_t(4000)}) {
      std::vector<std::vector<SignatureTable::Neighbour>> got(qs.size());
      table.nearest_many(qs.data(), qs.size(), 32, first, got.data(), threads);
      for (size_t q = 0; q < qs.size(); ++q) {
        std::vector<float> d(table.size());
        table.scaled_distances(qs[q], 0, table.size(), d.data());
        std::vector<SignatureTable::Neighbour> want;
        for (size_t e = first; e < table.size(); ++e) want.push_back({d[e], uint32_t(e)});
        std::sort(want.begin(), want.end());
        if (want.size() > 32) want.resize(32);
        REQUIRE(got[q].size() == want.size());
        for (size_t i = 0; i < want.size(); ++i) {
          CHECK(got[q][i].e == want[i].e);
          CHECK(same_bits(got[q][i].d, want[i].d));
        }
      }
    }
  }
  // The k nearest of the first 2300 entries, extended by 300 appended since, are nearest()'s.
  std::vector<std::vector<SignatureTable::Neighbour>> known(qs.size());
  table.nearest_many(qs.data(), qs.size(), 32, 0, known.data());
  for (int e = 2300; e < 2600; ++e) add(e);
  for (size_t q = 0; q < qs.size(); ++q) {
    table.extend(qs[q], 32, 2300, known[q]);
    std::vector<uint32_t> want;
    table.nearest(qs[q], 32, want);
    std::vector<uint32_t> got;
    for (const auto& n : known[q]) got.push_back(n.e);
    CHECK(got == want);
  }
}

TEST_CASE("the direction groups answer exactly: every query of a large mixed table equals scoring every entry") {
  // Directions in tight bundles (what code-book signatures are), spread ones, entries of norm 0,
  // entries opposite to the queries (distance |q|^2), duplicates, and queries of norm 0 and
  // between bundles: the groups must skip only entries that cannot be among the k nearest.
  std::mt19937 rng(21);
  std::normal_distribution<float> value(0.0f, 1.0f);
  const int width = 21;  // a P3 signature
  SignatureTable table(width);
  std::vector<std::vector<float>> bundles(40, std::vector<float>(size_t(width)));
  for (auto& b : bundles)
    for (float& v : b) v = 8.0f * value(rng);
  std::vector<std::vector<float>> rows;
  for (int e = 0; e < 6000; ++e) {
    std::vector<float> r(static_cast<size_t>(width));
    if (e % 97 == 13) {
      std::fill(r.begin(), r.end(), 0.0f);
    } else if (e % 11 == 5) {
      for (float& v : r) v = 8.0f * value(rng);
    } else if (e % 59 == 0 && e > 0) {
      r = rows[size_t(e / 2)];
    } else {
      const auto& b = bundles[size_t(e * 7) % bundles.size()];
      const float scale = 0.2f + 0.05f * float(e % 41);
      for (int i = 0; i < width; ++i) r[size_t(i)] = scale * (b[size_t(i)] + 0.15f * value(rng));
    }
    table.append(r.data());
    rows.push_back(r);
  }
  CHECK(table.groups() > 1);
  CHECK(table.groups() <= 64 + 2 * 78);  // the budget for 6000 entries
  std::vector<std::vector<float>> queries;
  for (int t = 0; t < 30; ++t) {
    std::vector<float> q = rows[size_t(t * 193) % rows.size()];
    for (float& v : q) v = v * 1.1f + (t % 4) * 0.3f * value(rng);
    queries.push_back(q);
  }
  queries.push_back(std::vector<float>(size_t(width), 0.0f));
  std::vector<float> between(static_cast<size_t>(width));
  for (int i = 0; i < width; ++i) between[size_t(i)] = bundles[0][size_t(i)] + bundles[1][size_t(i)];
  queries.push_back(between);
  for (auto& b : bundles) {
    std::vector<float> opposite = b;
    for (float& v : opposite) v = -v;
    queries.push_back(opposite);
  }
  for (const auto& q : queries)
    for (size_t first : {size_t(0), size_t(1000)})
      for (size_t k : {size_t(1), size_t(32), size_t(500)}) {
        std::vector<SignatureTable::Neighbour> want;
        for (size_t e = first; e < rows.size(); ++e)
          want.push_back({reference_distance(q.data(), rows[e].data(), width), uint32_t(e)});
        std::sort(want.begin(), want.end());
        want.resize(std::min(k, want.size()));
        std::vector<SignatureTable::Neighbour> got;
        const float* qp = q.data();
        table.nearest_many(&qp, 1, k, first, &got);
        REQUIRE(got.size() == want.size());
        for (size_t i = 0; i < want.size(); ++i) {
          CHECK(got[i].e == want[i].e);
          CHECK(same_bits(got[i].d, want[i].d));
        }
      }
}
