#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include <btfvq/error.h>
#include "pipeline/encode/proxy_index.h"

using namespace btfvq;

namespace {

std::vector<float> random_vectors(size_t n, int dim, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> centre(0.0f, 5.0f), spread(0.0f, 0.3f);
  std::vector<float> v;
  // Clusters, as code-book entries are: 20 centres with small spread.
  std::vector<float> centres(20 * size_t(dim));
  for (auto& c : centres) c = centre(rng);
  for (size_t i = 0; i < n; ++i)
    for (int d = 0; d < dim; ++d) v.push_back(centres[(i % 20) * size_t(dim) + size_t(d)] + spread(rng));
  return v;
}

std::vector<uint32_t> brute_force(const std::vector<float>& v, int dim, const float* q, int k) {
  const size_t n = v.size() / size_t(dim);
  std::vector<std::pair<float, uint32_t>> d;
  for (size_t i = 0; i < n; ++i) {
    float s = 0;
    for (int j = 0; j < dim; ++j) s += (v[i * size_t(dim) + size_t(j)] - q[j]) * (v[i * size_t(dim) + size_t(j)] - q[j]);
    d.push_back({s, uint32_t(i)});
  }
  std::sort(d.begin(), d.end());
  std::vector<uint32_t> out;
  for (int i = 0; i < k && size_t(i) < n; ++i) out.push_back(d[size_t(i)].second);
  return out;
}

}  // namespace

TEST_CASE("probing every list gives the exact nearest neighbours, nearest first") {
  const int dim = 11;
  const auto v = random_vectors(250, dim, 7);  // within the scan budget (256 members)
  ProxyIndex index(dim, 0.001f);  // far too small: the index must widen its radius itself
  for (size_t i = 0; i < v.size() / dim; ++i) index.insert(v.data() + i * dim);
  CHECK(index.size() == 250);
  CHECK(index.leaders() <= 64 + 2 * 15);
  const auto q = random_vectors(10, dim, 99);
  std::vector<uint32_t> got;
  for (int i = 0; i < 10; ++i) {
    index.nearest(q.data() + i * dim, 16, 1 << 20, got);
    CHECK(got == brute_force(v, dim, q.data() + i * dim, 16));
  }
  // More wanted than stored: every entry, in order.
  index.nearest(q.data(), 1000, 1 << 20, got);
  CHECK(got == brute_force(v, dim, q.data(), 1000));
  CHECK(got.size() == 250);
}

TEST_CASE("few probes still find the neighbours of a query inside a cluster") {
  const int dim = 11;
  const auto v = random_vectors(2000, dim, 3);
  ProxyIndex index(dim, 0.5f);
  for (size_t i = 0; i < v.size() / dim; ++i) index.insert(v.data() + i * dim);
  std::vector<uint32_t> got;
  size_t found = 0;
  for (size_t i = 0; i < 50; ++i) {
    const float* q = v.data() + (i * 37 % 2000) * dim;
    index.nearest(q, 8, 8, got);
    REQUIRE(!got.empty());
    const auto truth = brute_force(v, dim, q, 8);
    CHECK(got.front() == truth.front());  // the query itself is stored: distance 0
    for (uint32_t id : got) found += std::count(truth.begin(), truth.end(), id);
  }
  CHECK(found >= 50 * 8 * 9 / 10);
}

TEST_CASE("a dense region: every member of the probed lists is scanned, so the nearest one is found") {
  const int dim = 4;
  std::vector<float> v;
  for (int i = 0; i < 5000; ++i)
    for (int d = 0; d < dim; ++d) v.push_back(float((i * 7 + d * 13) % 100) * 1e-3f);  // one tight cluster
  ProxyIndex index(dim, 10.0f);  // one list holds everything
  for (int i = 0; i < 5000; ++i) index.insert(v.data() + i * dim);
  CHECK(index.leaders() == 1);
  std::vector<uint32_t> got;
  const float q[dim] = {0.05f, 0.06f, 0.07f, 0.08f};
  index.nearest(q, 8, 8, got);
  REQUIRE(got.size() == 8);
  const auto truth = brute_force(v, dim, q, 8);
  CHECK(got == truth);
}

TEST_CASE("a code-book of 100k entries returns an inserted near-duplicate, wherever it sits") {
  const int dim = 11;  // a P1 row's shape
  std::mt19937 rng(11);
  std::normal_distribution<float> n01(0.0f, 1.0f);
  std::vector<float> v;
  for (int i = 0; i < 100000; ++i) {
    // Smooth unit rows around a few dozen families (real rows crowd: dense lists).
    const int family = int(rng() % 40);
    double norm = 0;
    std::vector<float> row(dim);
    for (int d = 0; d < dim; ++d) {
      row[size_t(d)] = 1.0f + 0.5f * float(std::sin(0.3 * family * d)) + 0.05f * n01(rng);
      norm += double(row[size_t(d)]) * row[size_t(d)];
    }
    for (float& x : row) v.push_back(x / float(std::sqrt(norm)));
  }
  ProxyIndex index(dim, 0.02f);
  for (int i = 0; i < 100000; ++i) index.insert(v.data() + size_t(i) * dim);
  std::vector<uint32_t> got;
  for (const int target : {3, 511, 777, 40000, 99999}) {
    std::vector<float> q(v.begin() + target * dim, v.begin() + (target + 1) * dim);
    for (float& x : q) x += 1e-5f * n01(rng);
    index.nearest(q.data(), 4, 8, got);
    REQUIRE(!got.empty());
    CHECK(got.front() == uint32_t(target));
  }
}

TEST_CASE("an empty index returns nothing; a bad dimension or radius is an error") {
  ProxyIndex index(4, 1.0f);
  std::vector<uint32_t> got{1, 2};
  const float q[4] = {0, 0, 0, 0};
  index.nearest(q, 5, 3, got);
  CHECK(got.empty());
  CHECK_THROWS_AS(ProxyIndex(0, 1.0f), InputError);
  CHECK_THROWS_AS(ProxyIndex(3, 0.0f), InputError);
  CHECK_THROWS_AS(ProxyIndex(3, std::numeric_limits<float>::quiet_NaN()), InputError);
}

TEST_CASE("RowLanes: every row's distance is plain_distance's, whatever the number of rows") {
  for (int dim : {11, 22})
    for (size_t n : {0u, 1u, 7u, 8u, 9u, 1000u}) {
      const std::vector<float> rows = random_vectors(n, dim, uint32_t(n) + 3);
      const std::vector<float> q = random_vectors(1, dim, 99);
      RowLanes lanes(dim);
      for (size_t e = 0; e < n; ++e) lanes.append(&rows[e * size_t(dim)]);
      CHECK(lanes.size() == n);
      std::vector<float> d((n + RowLanes::kLanes - 1) / RowLanes::kLanes * RowLanes::kLanes, -1.0f);
      lanes.distances(q.data(), d.data());
      for (size_t e = 0; e < n; ++e) {
        // The reference: float differences, squared and summed in double in value order.
        double want = 0;
        for (int i = 0; i < dim; ++i) {
          const double x = double(q[size_t(i)] - rows[e * size_t(dim) + size_t(i)]);
          want += x * x;
        }
        CHECK(d[e] == float(want));
        CHECK(plain_distance(q.data(), &rows[e * size_t(dim)], dim) == float(want));
        std::vector<float> back(static_cast<size_t>(dim), -1.0f);
        lanes.row(e, back.data());
        CHECK(std::equal(back.begin(), back.end(), rows.begin() + ptrdiff_t(e * size_t(dim))));
      }
    }
}

TEST_CASE("RowLanes::nearest: the k nearest by (distance, index), on one thread or two, as sorting every row gives") {
  const int dim = 11;
  // Each vector 8 times (ties at every distance), from below to well above the size at which the
  // scan is spread over threads.
  for (size_t distinct : {3u, 500u, 2500u}) {
    const std::vector<float> once = random_vectors(distinct, dim, 17);
    RowLanes lanes(dim);
    std::vector<float> rows;
    for (int copy = 0; copy < 8; ++copy) rows.insert(rows.end(), once.begin(), once.end());
    const size_t n = rows.size() / dim;
    for (size_t e = 0; e < n; ++e) lanes.append(&rows[e * dim]);
    for (size_t at : {size_t(0), distinct / 2}) {
      const float* q = &once[at * dim];
      std::vector<Ranked> all;
      for (size_t e = 0; e < n; ++e) all.push_back({plain_distance(q, &rows[e * dim], dim), uint32_t(e)});
      std::sort(all.begin(), all.end());
      for (size_t k : {1u, 32u, 100u}) {
        const std::vector<Ranked> want(all.begin(), all.begin() + std::min(k, n));
        for (size_t threads : {1u, 2u}) {
          std::vector<Ranked> got;
          lanes.nearest(q, k, threads, got);
          REQUIRE(got.size() == want.size());
          for (size_t i = 0; i < want.size(); ++i) {
            CHECK(got[i].e == want[i].e);
            CHECK(got[i].d == want[i].d);
          }
        }
      }
    }
  }
}

TEST_CASE("equal distances: the k nearest are the lowest ids among them, as the linear scan has it") {
  const int dim = 11;
  const auto distinct = random_vectors(100, dim, 5);
  std::vector<float> v;
  for (int copy = 0; copy < 30; ++copy) v.insert(v.end(), distinct.begin(), distinct.end());  // each vector 30 times
  ProxyIndex index(dim, 0.5f);
  for (size_t i = 0; i < v.size() / dim; ++i) index.insert(v.data() + i * dim);
  std::vector<uint32_t> got;
  for (int i = 0; i < 100; i += 7) {
    index.nearest(distinct.data() + size_t(i) * dim, 40, 1 << 20, got);
    CHECK(got == brute_force(v, dim, distinct.data() + size_t(i) * dim, 40));
  }
}

TEST_CASE("an entry as near as the k-th but of a lower id, in a list probed later, takes its place") {
  // q = 0; list A (leader at distance 10) holds id 2 at distance 10; list B (leader at 10.5) holds
  // id 1 at distance 10 too, among 15 farther members: the tie goes to the lower id.
  ProxyIndex index(2, 1.0f);
  const float b_leader[2] = {-10.5f, 0.0f}, tie[2] = {-10.0f, 0.0f}, a[2] = {10.0f, 0.0f};
  index.insert(b_leader);
  index.insert(tie);
  index.insert(a);
  for (int j = 1; j <= 14; ++j) {
    const float member[2] = {-10.5f, 0.05f * float(j)};
    index.insert(member);
  }
  REQUIRE(index.leaders() == 2);
  const float q[2] = {0.0f, 0.0f};
  std::vector<uint32_t> got;
  index.nearest(q, 1, 2, got);
  CHECK(got == std::vector<uint32_t>{1});
  index.nearest(q, 2, 2, got);
  CHECK(got == std::vector<uint32_t>{1, 2});
}
