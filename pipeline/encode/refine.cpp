#include "pipeline/encode/refine.h"

#include <algorithm>
#include <cmath>
#include <future>
#include <iterator>
#include <limits>
#include <map>
#include <stdexcept>

#include <btfvq/error.h>
#include <spdlog/spdlog.h>
#include "pipeline/encode/similarity.h"
#include "pipeline/util/parallel.h"

namespace btfvq {

void TilePrefetch::fetch(const uint32_t* ids, size_t n) {
  if (pending_.valid()) throw std::logic_error("TilePrefetch: fetch() before the last fetch was taken");
  filling_ ^= 1;
  std::vector<float>& b = buffers_[filling_];
  pending_ = std::async(std::launch::async, [this, &b, ids, n] {
    b.resize(n * values_);
    source_(ids, n, b.data());
  });
}

const float* TilePrefetch::take() {
  pending_.get();  // rethrows the source's error
  return buffers_[filling_].data();
}

void for_each_tile(const uint32_t* ids, size_t count, const TexelSource& source, size_t tile, size_t values,
                   const std::function<void(size_t at, size_t n, const float* x)>& f) {
  tile = std::max<size_t>(tile, 1);
  TilePrefetch tiles(source, values);
  if (count > 0) tiles.fetch(ids, std::min(tile, count));
  for (size_t at = 0; at < count; at += tile) {
    const float* x = tiles.take();
    if (at + tile < count) tiles.fetch(ids + at + tile, std::min(tile, count - at - tile));
    f(at, std::min(tile, count - at), x);
  }
}

RefineSettings RefineSettings::from(const ParameterDictionary& d) {
  RefineSettings s;
  s.iterations = d.integer("refine.iterations", 0, 100);
  s.fraction = d.number("refine.fraction", 0.0, 1.0);
  s.min_gain = d.number("refine.min_gain", 0.0, 1.0);
  s.merge.p1 = d.number("refine.p1_merge", 0.0, 2.0);
  s.merge.p2 = d.number("refine.p2_merge", 0.0, 1000.0);
  s.merge.i1 = d.number("refine.i1_merge", 0.0, 1000.0);
  s.merge.i2 = d.number("refine.i2_merge", 0.0, 1000.0);
  s.merge.budget = d.number("refine.merge_budget", 0.0, 100.0);
  return s;
}

namespace {

// Rounds of the alternating updates inside one step: each is exact, so more only cost time; a few
// take most of the gain because the blocks are only weakly coupled.
constexpr int kLuminanceRounds = 4;
constexpr int kChromaRounds = 2;
constexpr int kScaleRounds = 3;

// Values below this are stored as 0: a least-squares density of a few 1e-7 would stretch the
// logarithmic quantization range of the whole chunk (docs/format.md) for nothing visible.
constexpr float kTiny = 1e-6f;

// Directions of most spread whose projections bound the distance of two rows in the merges' search.
constexpr size_t kMergeDirections = 6;

float non_negative(double v) { return v > double(kTiny) ? float(v) : 0.0f; }

struct Layout {
  int nb, na, nt, np;
  size_t samples;
  explicit Layout(const AngularGrid& g)
      : nb(g.n_beta), na(g.n_alpha), nt(g.n_theta_v), np(g.n_phi_v), samples(g.samples()) {}
  int planes() const { return np * nt; }
};

// What the texels say about the lower code-books, given the scales above them.
struct LowerSums {
  // Per added P2 row and alpha: sum of S^2 z_b (z the target of ps d_b) and of S^2.
  std::vector<double> lum, lum_w;
  // Per added I1 row and beta: sum of w z (two chroma channels) and of w.
  std::vector<double> chroma, chroma_w;
  // Per added I2 row: sum of w over its uses (planes).
  std::vector<double> i2_w;
};

// Per texel and plane, what the plane scales see: alpha = (L - o).(x - o), beta = |L - o|^2 over the
// scaled channels; per texel the rest of its squared error.
struct PlaneSums {
  std::vector<double> alpha, beta;  // texel-major, planes() each
  std::vector<double> gamma;        // per texel: |x - o|^2 over the scaled channels + unscaled error
};

// Calls f(t, x) for every texel t of the assignment with its values x (tiles as for_each_tile). With
// `threads` != 1 the texels of a tile are spread over the threads: only for an f that writes
// nothing but texel t's own outputs.
template <class F>
void for_each_texel(const Assignment& a, const TexelSource& source, size_t tile, size_t values, size_t threads, F&& f) {
  for_each_tile(a.ids.data(), a.ids.size(), source, tile, values, [&](size_t at, size_t n, const float* x) {
    parallel_for(0, n, [&](size_t i) { f(at + i, x + i * values); }, ParallelOptions{threads, 1});
  });
}

// Pass over the data with the current code-books (each tile assigned first, with `assign`): the
// sums of LowerSums and the squared error.
double lower_sums(const Codebooks& k, const CodebookSizes& first, Dynamic dyn, Assignment& as,
                  const TexelSource& source, size_t tile, const AssignTile& assign, LowerSums& out) {
  const Layout L(k.grid);
  const size_t p2_first = first[CodebookId::P2], i1_first = first[CodebookId::I1];
  out.lum.assign((k.p2_index.rows() - p2_first) * size_t(L.na * L.nb), 0.0);
  out.lum_w.assign((k.p2_index.rows() - p2_first) * size_t(L.na), 0.0);
  out.chroma.assign((k.i1.rows() - i1_first) * size_t(L.nb) * 2, 0.0);
  out.chroma_w.assign((k.i1.rows() - i1_first) * size_t(L.nb), 0.0);
  const size_t i2_first = first[CodebookId::I2];
  out.i2_w.assign(k.i2.rows() - i2_first, 0.0);
  const float oy = channel_offset(dyn, 0), oc = channel_offset(dyn, 1);
  const bool chroma_scales = channel_scales(dyn, 1);
  double error = 0;
  auto sums = [&](size_t t, const float* x) {
    const float s6 = as.scale[t];
    const uint32_t p4 = as.p4[t];
    if (p4 >= k.p4_index.rows()) throw InputError("refine_step: a P4 index past the end of P4");
    for (int p = 0; p < L.np; ++p) {
      const uint32_t p3 = k.p4_index.at(p4, size_t(p));
      const float s4 = s6 * k.p4_scale.at(p4, size_t(p));
      for (int th = 0; th < L.nt; ++th) {
        const uint32_t m = k.p3_index.at(p3, size_t(th));
        const double S = double(s4) * k.p3_scale.at(p3, size_t(th)), S2 = S * S;
        const uint32_t q = k.m.at(m, 0), j = k.m.at(m, 1);
        if (j >= i2_first) out.i2_w[j - i2_first] += chroma_scales ? S2 : 1.0;
        for (int a = 0; a < L.na; ++a) {
          const float* d = k.p1.row(k.p2_index.at(q, size_t(a)));
          const double ps = k.p2_scale.at(q, size_t(a));
          const uint32_t i1 = k.i2.at(j, size_t(a));
          const uint32_t* colours = k.i1.row(i1);
          const size_t i = k.grid.index(p, th, a, 0);
          const float* y = x + i;
          const float* cb = x + L.samples + i;
          const float* cr = x + 2 * L.samples + i;
          double* lum = q >= p2_first ? &out.lum[((q - p2_first) * size_t(L.na) + size_t(a)) * size_t(L.nb)] : nullptr;
          if (lum) out.lum_w[(q - p2_first) * size_t(L.na) + size_t(a)] += S2;
          const bool chroma_new = i1 >= i1_first;
          for (int b = 0; b < L.nb; ++b) {
            const double ry = oy + S * (ps * d[b] - oy);
            const float* c = k.c.row(colours[b]);
            const double rcb = chroma_scales ? oc + S * (c[0] - oc) : c[0];
            const double rcr = chroma_scales ? oc + S * (c[1] - oc) : c[1];
            error += (ry - y[b]) * (ry - y[b]) + (rcb - cb[b]) * (rcb - cb[b]) + (rcr - cr[b]) * (rcr - cr[b]);
            if (lum) lum[b] += S * (y[b] - oy) + S2 * oy;
            if (chroma_new) {
              const size_t at = (i1 - i1_first) * size_t(L.nb) + size_t(b);
              if (chroma_scales) {
                out.chroma[2 * at] += S * (cb[b] - oc) + S2 * oc;
                out.chroma[2 * at + 1] += S * (cr[b] - oc) + S2 * oc;
                out.chroma_w[at] += S2;
              } else {
                out.chroma[2 * at] += cb[b];
                out.chroma[2 * at + 1] += cr[b];
                out.chroma_w[at] += 1;
              }
            }
          }
        }
      }
    }
  };
  const size_t values = 3 * L.samples;
  for_each_tile(as.ids.data(), as.ids.size(), source, tile, values, [&](size_t at, size_t n, const float* x) {
    if (assign) assign(x, n, &as.p4[at], &as.scale[at]);
    for (size_t i = 0; i < n; ++i) sums(at + i, x + i * values);
  });
  return error;
}

// Orthonormal directions (at most k, each dim values) along which the rows spread most: subspace iteration
// on the covariance of (at most 4,096 of) the rows. Any orthonormal directions give a true lower
// bound on the distance of two rows, the sum of their squared differences along them; these make
// it tight. Deterministic: one thread, fixed order.
std::vector<double> spread_directions(const std::vector<float>& rows, size_t dim, const std::vector<uint32_t>& use,
                                      size_t k) {
  const size_t step = std::max<size_t>(1, use.size() / 4096);
  std::vector<double> mean(dim, 0.0), cov(dim * dim, 0.0), x(dim);
  size_t count = 0;
  for (size_t i = 0; i < use.size(); i += step, ++count)
    for (size_t v = 0; v < dim; ++v) mean[v] += rows[size_t(use[i]) * dim + v];
  for (double& m : mean) m /= double(std::max<size_t>(count, 1));
  for (size_t i = 0; i < use.size(); i += step) {
    for (size_t v = 0; v < dim; ++v) x[v] = rows[size_t(use[i]) * dim + v] - mean[v];
    for (size_t u = 0; u < dim; ++u)
      for (size_t v = 0; v < dim; ++v) cov[u * dim + v] += x[u] * x[v];
  }
  std::vector<double> q(k * dim), y(k * dim);
  for (size_t j = 0; j < k; ++j)
    for (size_t v = 0; v < dim; ++v) q[j * dim + v] = v == j ? 1.0 : 1.0 / double(dim + j + v);  // a fixed start
  auto orthonormalize = [&](std::vector<double>& m) {  // Gram-Schmidt, twice for accuracy
    for (int pass = 0; pass < 2; ++pass)
      for (size_t j = 0; j < k; ++j) {
        double* a = &m[j * dim];
        for (size_t i = 0; i < j; ++i) {
          const double* e = &m[i * dim];
          double dot = 0;
          for (size_t v = 0; v < dim; ++v) dot += a[v] * e[v];
          for (size_t v = 0; v < dim; ++v) a[v] -= dot * e[v];
        }
        double norm = 0;
        for (size_t v = 0; v < dim; ++v) norm += a[v] * a[v];
        norm = std::sqrt(norm);
        for (size_t v = 0; v < dim; ++v) a[v] = norm > 0 ? a[v] / norm : (v == j ? 1.0 : 0.0);
      }
  };
  orthonormalize(q);
  for (int it = 0; it < 30; ++it) {
    for (size_t j = 0; j < k; ++j)
      for (size_t u = 0; u < dim; ++u) {
        double sum = 0;
        for (size_t v = 0; v < dim; ++v) sum += cov[u * dim + v] * q[j * dim + v];
        y[j * dim + u] = sum;
      }
    q.swap(y);
    orthonormalize(q);
  }
  // Only an orthonormal prefix bounds the distance: degenerate rows (rank below k) could leave a
  // direction that Gram-Schmidt had to replace by a unit vector in the span of the others.
  size_t valid = 1;
  for (; valid < k; ++valid) {
    bool orthogonal = true;
    for (size_t i = 0; i < valid && orthogonal; ++i) {
      double dot = 0;
      for (size_t v = 0; v < dim; ++v) dot += q[valid * dim + v] * q[i * dim + v];
      orthogonal = std::fabs(dot) < 1e-12;
    }
    if (!orthogonal) break;
  }
  q.resize(valid * dim);
  return q;
}

// The leaders found so far, sorted by their first projection, with a copy of their projections
// and rows in that order (a search walks them contiguously). seq: the order in which they became
// leaders; a tie goes to the earliest.
class LeaderSet {
 public:
  LeaderSet(size_t dim, size_t k, double slack) : dim_(dim), k_(k), slack_(slack) {}

  struct Found {
    double d;
    uint32_t seq = UINT32_MAX;  // UINT32_MAX: none within reach
  };

  // Whether the projections alone put a leader past f (with a margin for rounding, so that the
  // search finds what the exhaustive one does).
  bool far(double bound, const Found& f) const { return bound > f.d * (1 + 1e-9) + slack_; }
  double bound(const double* a, const double* b) const {
    double sum = 0;
    for (size_t j = 0; j < k_; ++j) sum += (a[j] - b[j]) * (a[j] - b[j]);
    return sum;
  }

  // The nearest leader to x (projections px) within `reach`: outward from x's first projection
  // until that alone passes the nearest found, skipping leaders that all k put past it.
  Found nearest(const float* x, const double* px, double reach) const {
    Found f{reach};
    const size_t start = size_t(std::lower_bound(key_.begin(), key_.end(), px[0]) - key_.begin());
    auto visit = [&](size_t i) {
      if (far((key_[i] - px[0]) * (key_[i] - px[0]), f)) return false;
      offer(x, px, &rows_[i * dim_], &proj_[i * k_], seq_[i], f);
      return true;
    };
    for (size_t i = start; i < key_.size() && visit(i); ++i) {
    }
    for (size_t i = start; i-- > 0 && visit(i);) {
    }
    return f;
  }

  // Offers leader y (projections py, seq) to x's search unless the projections alone put it past f.
  void offer(const float* x, const double* px, const float* y, const double* py, uint32_t seq, Found& f) const {
    if (!far(bound(py, px), f)) consider(x, y, seq, f);
  }

  // Considers leader y (seq) for x: nearer, or as near and earlier, than f.
  void consider(const float* x, const float* y, uint32_t seq, Found& f) const {
    double d = 0;
    for (size_t v = 0; v < dim_ && d <= f.d; ++v) d += double(x[v] - y[v]) * (x[v] - y[v]);
    if (d < f.d || (d == f.d && seq < f.seq)) f = {d, seq};
  }

  // Adds leaders (rows and their k projections) whose seq continue the set's.
  void add(const std::vector<const float*>& rows, const std::vector<const double*>& proj) {
    if (rows.empty()) return;
    const size_t old = key_.size();
    auto proj_of = [&](size_t i) { return i < old ? &proj_[i * k_] : proj[i - old]; };
    auto by_key = [&](size_t a, size_t b) { return proj_of(a)[0] < proj_of(b)[0]; };
    // The leaders already held are in key order: sort the new ones and merge, old first on ties.
    std::vector<size_t> held(old), fresh(rows.size()), order;
    for (size_t i = 0; i < old; ++i) held[i] = i;
    for (size_t i = 0; i < fresh.size(); ++i) fresh[i] = old + i;
    std::stable_sort(fresh.begin(), fresh.end(), by_key);
    order.reserve(old + fresh.size());
    std::merge(held.begin(), held.end(), fresh.begin(), fresh.end(), std::back_inserter(order), by_key);
    std::vector<double> key(order.size()), projections(order.size() * k_);
    std::vector<uint32_t> seq(order.size());
    std::vector<float> values(order.size() * dim_);
    for (size_t at = 0; at < order.size(); ++at) {
      const size_t i = order[at];
      key[at] = proj_of(i)[0];
      std::copy_n(proj_of(i), k_, &projections[at * k_]);
      seq[at] = i < old ? seq_[i] : uint32_t(old + (i - old));
      std::copy_n(i < old ? &rows_[i * dim_] : rows[i - old], dim_, &values[at * dim_]);
    }
    key_.swap(key);
    proj_.swap(projections);
    seq_.swap(seq);
    rows_.swap(values);
  }

  size_t count() const { return key_.size(); }

 private:
  size_t dim_, k_;
  double slack_;
  std::vector<double> key_, proj_;
  std::vector<uint32_t> seq_;
  std::vector<float> rows_;
};

}  // namespace

// Rows are taken in batches: each row of a batch finds its nearest leader among those before the
// batch in parallel, then the batch is settled in order against the leaders it made itself, so the
// result is the row-by-row one for any thread count and batch size.
std::vector<uint32_t> merge_leaders(const std::vector<float>& rows, size_t dim, const std::vector<double>& weight,
                                    double radius, double budget, size_t threads) {
  const size_t n = weight.size();
  if (rows.size() != n * dim) throw InputError("merge_leaders: rows and weights differ in number");
  std::vector<uint32_t> leader(n);
  for (size_t r = 0; r < n; ++r) leader[r] = uint32_t(r);
  std::vector<uint32_t> order;
  double mean_weight = 0;
  for (uint32_t r = 0; r < n; ++r)
    if (weight[r] > 0) {
      order.push_back(r);
      mean_weight += weight[r];
    }
  if (order.empty() || !(radius > 0) || dim == 0) return leader;
  mean_weight /= double(order.size());
  std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return weight[a] > weight[b]; });
  auto reach = [&](uint32_t r) { return radius * radius * mean_weight / weight[r]; };

  // Every row's projections on the directions of most spread. Their rounding (about dim^1.5 x 1e-16
  // of the largest value each) moves the bound by far less than the slack, 1e-12 x dim x that value^2.
  const std::vector<double> directions = spread_directions(rows, dim, order, std::min<size_t>(dim, kMergeDirections));
  const size_t k = directions.size() / dim;
  std::vector<double> proj(n * k);
  double longest = 0;
  parallel_for(0, n, [&](size_t r) {
    for (size_t j = 0; j < k; ++j) {
      double sum = 0;
      for (size_t v = 0; v < dim; ++v) sum += directions[j * dim + v] * rows[r * dim + v];
      proj[r * k + j] = sum;
    }
  }, ParallelOptions{threads});
  for (float v : rows) longest = std::max(longest, double(std::fabs(v)));
  const double slack = 1e-12 * double(dim) * longest * longest;

  constexpr size_t kBatch = 256;
  LeaderSet leaders(dim, k, slack);
  std::vector<uint32_t> by_seq;  // row of each leader
  std::vector<LeaderSet::Found> found(kBatch);
  std::vector<std::pair<double, uint32_t>> merges;  // (added error, row)
  for (size_t at = 0; at < order.size(); at += kBatch) {
    const size_t count = std::min(kBatch, order.size() - at);
    parallel_for(0, count, [&](size_t j) {
      const uint32_t r = order[at + j];
      found[j] = leaders.nearest(&rows[size_t(r) * dim], &proj[r * k], reach(r));
    }, ParallelOptions{threads, 8});
    std::vector<const float*> added;
    std::vector<const double*> added_proj;
    for (size_t j = 0; j < count; ++j) {
      const uint32_t r = order[at + j];
      const float* x = &rows[size_t(r) * dim];
      LeaderSet::Found f = found[j];
      for (size_t i = 0; i < added.size(); ++i)  // later than any leader before the batch
        leaders.offer(x, &proj[r * k], added[i], added_proj[i], uint32_t(leaders.count() + i), f);
      if (f.seq == UINT32_MAX) {
        added.push_back(x);
        added_proj.push_back(&proj[r * k]);
        by_seq.push_back(r);
      } else {
        leader[r] = by_seq[f.seq];
        merges.emplace_back(weight[r] * f.d, r);
      }
    }
    leaders.add(added, added_proj);
  }
  std::sort(merges.begin(), merges.end());
  double spent = 0, kept = 0;
  size_t merged = 0;
  for (const auto& [cost, r] : merges) {
    spent += cost;
    if (spent > budget) {
      leader[r] = r;
    } else {
      kept = spent;
      ++merged;
    }
  }
  spdlog::debug("refine: rows of {} values: {} of {} merges kept, adding {:.4g} of a budget of {:.4g}", dim, merged,
                merges.size(), kept, budget);
  return leader;
}

namespace {

// Adds the sums of every merged row (`per_row` values each) to its leader's.
void move_sums(const std::vector<uint32_t>& leader, size_t per_row, std::vector<double>& sums) {
  for (size_t r = 0; r < leader.size(); ++r)
    if (leader[r] != r)
      for (size_t v = 0; v < per_row; ++v) {
        sums[leader[r] * per_row + v] += sums[r * per_row + v];
        sums[r * per_row + v] = 0;
      }
}

// Points the indices at or past `from` in columns [c0, c1) of the rows at or past `rows_from` at the leaders.
void redirect(Table<uint32_t>& table, size_t rows_from, size_t c0, size_t c1, size_t from,
              const std::vector<uint32_t>& leader) {
  for (size_t r = rows_from; r < table.rows(); ++r)
    for (size_t c = c0; c < c1; ++c) {
      uint32_t& i = table.at(r, c);
      if (i >= from) i = uint32_t(from + leader[i - from]);
    }
}

// Added M rows that became equal are one (the first); added P3 rows point at it.
void unify_m(Codebooks& k, const CodebookSizes& first) {
  const size_t m_first = first[CodebookId::M];
  std::map<std::pair<uint32_t, uint32_t>, uint32_t> by_content;
  std::vector<uint32_t> same(k.m.rows() - m_first);
  for (size_t r = m_first; r < k.m.rows(); ++r)
    same[r - m_first] = by_content.emplace(std::make_pair(k.m.at(r, 0), k.m.at(r, 1)), uint32_t(r)).first->second - uint32_t(m_first);
  redirect(k.p3_index, first[CodebookId::P3], 0, k.p3_index.cols(), m_first, same);
}

// Added P1 rows (densities) merged; P2 rows point at the leaders, whose centres the next rounds
// fit to all of their uses. The growing phases' repairs store most P1 rows exactly, one per
// failing slice row, so many are near-copies of each other.
void merge_p1(Codebooks& k, const CodebookSizes& first, const LowerSums& s, double radius, double budget,
              size_t threads) {
  const size_t nb = k.grid.n_beta, na = k.grid.n_alpha, p1_first = first[CodebookId::P1], p2_first = first[CodebookId::P2];
  std::vector<double> w(k.p1.rows() - p1_first, 0.0);
  for (size_t q = p2_first; q < k.p2_index.rows(); ++q)
    for (size_t a = 0; a < na; ++a) {
      const uint32_t e = k.p2_index.at(q, a);
      const double ps = k.p2_scale.at(q, a);
      if (e >= p1_first) w[e - p1_first] += ps * ps * s.lum_w[(q - p2_first) * na + a];
    }
  const std::vector<float> rows(k.p1.data().begin() + ptrdiff_t(p1_first * nb), k.p1.data().end());
  redirect(k.p2_index, p2_first, 0, na, p1_first, merge_leaders(rows, nb, w, radius, budget, threads));
}

// Added P2 rows merged by their decoded slices (a row's weight is S^2 summed over the planes that
// use it, the same for every alpha); their sums move to the leader, M rows follow.
void merge_p2(Codebooks& k, const CodebookSizes& first, LowerSums& s, double radius, double budget, size_t threads) {
  const size_t nb = k.grid.n_beta, na = k.grid.n_alpha, p2_first = first[CodebookId::P2];
  const size_t n = k.p2_index.rows() - p2_first;
  std::vector<float> slices(n * na * nb);
  std::vector<double> w(n);
  for (size_t q = 0; q < n; ++q) {
    w[q] = s.lum_w[q * na];
    for (size_t a = 0; a < na; ++a) {
      const float* d = k.p1.row(k.p2_index.at(p2_first + q, a));
      for (size_t b = 0; b < nb; ++b) slices[(q * na + a) * nb + b] = k.p2_scale.at(p2_first + q, a) * d[b];
    }
  }
  const std::vector<uint32_t> leader = merge_leaders(slices, na * nb, w, radius, budget, threads);
  move_sums(leader, na * nb, s.lum);
  move_sums(leader, na, s.lum_w);
  redirect(k.m, first[CodebookId::M], 0, 1, p2_first, leader);
  unify_m(k, first);
}

// Decoded chroma of an I1 row: n_beta (a, b) pairs.
void i1_values(const Codebooks& k, uint32_t r, float* out) {
  for (size_t b = 0; b < k.i1.cols(); ++b) {
    out[2 * b] = k.c.at(k.i1.at(r, b), 0);
    out[2 * b + 1] = k.c.at(k.i1.at(r, b), 1);
  }
}

// Added I1 rows merged by their decoded chroma (weight: w summed over their uses, the same for every
// beta); their sums move to the leader, I2 rows follow.
void merge_i1(Codebooks& k, const CodebookSizes& first, LowerSums& s, double radius, double budget, size_t threads) {
  const size_t nb = k.grid.n_beta, i1_first = first[CodebookId::I1], n = k.i1.rows() - i1_first;
  std::vector<float> rows(n * 2 * nb);
  std::vector<double> w(n);
  for (size_t r = 0; r < n; ++r) {
    w[r] = s.chroma_w[r * nb];
    i1_values(k, uint32_t(i1_first + r), &rows[r * 2 * nb]);
  }
  const std::vector<uint32_t> leader = merge_leaders(rows, 2 * nb, w, radius, budget, threads);
  move_sums(leader, 2 * nb, s.chroma);
  move_sums(leader, nb, s.chroma_w);
  redirect(k.i2, first[CodebookId::I2], 0, k.i2.cols(), i1_first, leader);
}

// Added I2 rows merged by their decoded chroma slices; M rows follow. Last of the chroma updates:
// the sums are kept per I1 row, so a merged I2 row's share cannot be moved.
void merge_i2(Codebooks& k, const CodebookSizes& first, const LowerSums& s, double radius, double budget,
              size_t threads) {
  const size_t nb = k.grid.n_beta, na = k.grid.n_alpha, i2_first = first[CodebookId::I2], n = k.i2.rows() - i2_first;
  std::vector<float> rows(n * na * 2 * nb);
  for (size_t r = 0; r < n; ++r)
    for (size_t a = 0; a < na; ++a) i1_values(k, k.i2.at(i2_first + r, a), &rows[(r * na + a) * 2 * nb]);
  const std::vector<uint32_t> leader = merge_leaders(rows, na * 2 * nb, s.i2_w, radius, budget, threads);
  redirect(k.m, first[CodebookId::M], 1, 2, i2_first, leader);
  unify_m(k, first);
}

// P1 rows at their least-squares centre, then P2 scales refitted, alternately. A density is kept
// summing to 1 by moving its sum into the P2 scales that use it (the product is what decodes).
void update_luminance(Codebooks& k, const CodebookSizes& first, LowerSums& s, const RefineMerge& merge, double budget,
                      size_t threads) {
  const size_t nb = k.grid.n_beta, na = k.grid.n_alpha;
  const size_t p1_first = first[CodebookId::P1], p2_first = first[CodebookId::P2];
  const size_t p2_rows = k.p2_index.rows();
  std::vector<double> num, den;
  for (int round = 0; round < kLuminanceRounds; ++round) {
    if (round == 1 && merge.p1 > 0) merge_p1(k, first, s, merge.p1, budget, threads);
    if (round == 2 && merge.p2 > 0) merge_p2(k, first, s, merge.p2, budget, threads);
    num.assign((k.p1.rows() - p1_first) * nb, 0.0);
    den.assign(k.p1.rows() - p1_first, 0.0);
    for (size_t q = p2_first; q < p2_rows; ++q)
      for (size_t a = 0; a < na; ++a) {
        const uint32_t e = k.p2_index.at(q, a);
        if (e < p1_first) continue;
        const double ps = k.p2_scale.at(q, a);
        const double* A = &s.lum[((q - p2_first) * na + a) * nb];
        for (size_t b = 0; b < nb; ++b) num[(e - p1_first) * nb + b] += ps * A[b];
        den[e - p1_first] += ps * ps * s.lum_w[(q - p2_first) * na + a];
      }
    std::vector<double> moved(k.p1.rows() - p1_first, 1.0);
    for (size_t e = p1_first; e < k.p1.rows(); ++e) {
      const double w = den[e - p1_first];
      if (!(w > 0)) continue;
      float row[1024];
      double sum = 0;
      for (size_t b = 0; b < nb; ++b) sum += row[b] = non_negative(num[(e - p1_first) * nb + b] / w);
      if (!(sum > 0)) continue;
      for (size_t b = 0; b < nb; ++b) k.p1.at(e, b) = non_negative(row[b] / sum);
      moved[e - p1_first] = sum;
    }
    for (size_t q = p2_first; q < p2_rows; ++q)
      for (size_t a = 0; a < na; ++a) {
        const uint32_t e = k.p2_index.at(q, a);
        if (e >= p1_first) k.p2_scale.at(q, a) = float(k.p2_scale.at(q, a) * moved[e - p1_first]);
        const double w = s.lum_w[(q - p2_first) * na + a];
        if (!(w > 0)) continue;
        const float* d = k.p1.row(e);
        const double* A = &s.lum[((q - p2_first) * na + a) * nb];
        double dA = 0, dd = 0;
        for (size_t b = 0; b < nb; ++b) {
          dA += d[b] * A[b];
          dd += double(d[b]) * d[b];
        }
        if (dd > 0) k.p2_scale.at(q, a) = non_negative(dA / (dd * w));
      }
  }
}

// C entries at the centre of the chroma that reaches them, then every added I1 row's colour the
// nearest entry to what reaches it (all of C: published entries are fine to point at).
void update_chroma(Codebooks& k, const CodebookSizes& first, LowerSums& s, const RefineMerge& merge, double budget,
                   size_t threads) {
  const size_t nb = k.grid.n_beta, c_first = first[CodebookId::C], i1_first = first[CodebookId::I1];
  const size_t i1_rows = k.i1.rows(), c_rows = k.c.rows();
  for (int round = 0; round < kChromaRounds; ++round) {
    if (round == 1 && merge.i1 > 0) merge_i1(k, first, s, merge.i1, budget, threads);
    std::vector<double> num(2 * (c_rows - c_first), 0.0), den(c_rows - c_first, 0.0);
    for (size_t r = i1_first; r < i1_rows; ++r)
      for (size_t b = 0; b < nb; ++b) {
        const uint32_t c = k.i1.at(r, b);
        if (c < c_first) continue;
        const size_t at = (r - i1_first) * nb + b;
        num[2 * (c - c_first)] += s.chroma[2 * at];
        num[2 * (c - c_first) + 1] += s.chroma[2 * at + 1];
        den[c - c_first] += s.chroma_w[at];
      }
    for (size_t c = c_first; c < c_rows; ++c)
      if (den[c - c_first] > 0) {
        k.c.at(c, 0) = float(num[2 * (c - c_first)] / den[c - c_first]);
        k.c.at(c, 1) = float(num[2 * (c - c_first) + 1] / den[c - c_first]);
      }
    for (size_t r = i1_first; r < i1_rows; ++r)
      for (size_t b = 0; b < nb; ++b) {
        const size_t at = (r - i1_first) * nb + b;
        const double w = s.chroma_w[at];
        if (!(w > 0)) continue;
        const double ca = s.chroma[2 * at] / w, cb = s.chroma[2 * at + 1] / w;
        double best = std::numeric_limits<double>::infinity();
        for (size_t c = 0; c < c_rows; ++c) {
          const double da = k.c.at(c, 0) - ca, db = k.c.at(c, 1) - cb, e = da * da + db * db;
          if (e < best) {
            best = e;
            k.i1.at(r, b) = uint32_t(c);
          }
        }
      }
  }
}

// Pass over the data with the updated lower code-books: PlaneSums.
void plane_sums(const Codebooks& k, Dynamic dyn, const Assignment& as, const TexelSource& source, size_t tile,
                size_t threads, PlaneSums& out) {
  const Layout L(k.grid);
  const size_t planes = size_t(L.planes());
  out.alpha.assign(as.ids.size() * planes, 0.0);
  out.beta.assign(as.ids.size() * planes, 0.0);
  out.gamma.assign(as.ids.size(), 0.0);
  double o[3];
  bool scaled[3];
  for (int c = 0; c < 3; ++c) {
    o[c] = channel_offset(dyn, c);
    scaled[c] = channel_scales(dyn, c);
  }
  for_each_texel(as, source, tile, 3 * L.samples, threads, [&](size_t t, const float* x) {  // texel t's sums only
    const uint32_t p4 = as.p4[t];
    double gamma = 0;
    for (int p = 0; p < L.np; ++p) {
      const uint32_t p3 = k.p4_index.at(p4, size_t(p));
      for (int th = 0; th < L.nt; ++th) {
        const uint32_t m = k.p3_index.at(p3, size_t(th));
        const uint32_t q = k.m.at(m, 0), j = k.m.at(m, 1);
        double al = 0, be = 0;
        for (int a = 0; a < L.na; ++a) {
          const float* d = k.p1.row(k.p2_index.at(q, size_t(a)));
          const double ps = k.p2_scale.at(q, size_t(a));
          const uint32_t* colours = k.i1.row(k.i2.at(j, size_t(a)));
          const size_t i = k.grid.index(p, th, a, 0);
          for (int b = 0; b < L.nb; ++b) {
            const float* c = k.c.row(colours[b]);
            const double v[3] = {ps * d[b], c[0], c[1]};
            for (int ch = 0; ch < 3; ++ch) {
              const double xv = x[size_t(ch) * L.samples + i + size_t(b)];
              if (scaled[ch]) {
                al += (v[ch] - o[ch]) * (xv - o[ch]);
                be += (v[ch] - o[ch]) * (v[ch] - o[ch]);
                gamma += (xv - o[ch]) * (xv - o[ch]);
              } else {
                gamma += (v[ch] - xv) * (v[ch] - xv);
              }
            }
          }
        }
        out.alpha[t * planes + size_t(p * L.nt + th)] = al;
        out.beta[t * planes + size_t(p * L.nt + th)] = be;
      }
    }
    out.gamma[t] = gamma;
  });
}

double plane_error(const Codebooks& k, const Assignment& as, const PlaneSums& s) {
  const Layout L(k.grid);
  const size_t planes = size_t(L.planes());
  double error = 0;
  for (size_t t = 0; t < as.ids.size(); ++t) {
    double e = s.gamma[t];
    for (int p = 0; p < L.np; ++p) {
      const uint32_t p3 = k.p4_index.at(as.p4[t], size_t(p));
      const double s4 = double(as.scale[t]) * k.p4_scale.at(as.p4[t], size_t(p));
      for (int th = 0; th < L.nt; ++th) {
        const double S = s4 * k.p3_scale.at(p3, size_t(th));
        const size_t at = t * planes + size_t(p * L.nt + th);
        e += S * (S * s.beta[at] - 2 * s.alpha[at]);
      }
    }
    error += e;
  }
  return error;
}

// P3 scales, P4 scales and P6 scales refitted one block after the other.
void update_scales(Codebooks& k, const CodebookSizes& first, Assignment& as, const PlaneSums& s) {
  const Layout L(k.grid);
  const size_t planes = size_t(L.planes()), nt = size_t(L.nt), np = size_t(L.np);
  const size_t p3_first = first[CodebookId::P3], p4_first = first[CodebookId::P4];
  for (int round = 0; round < kScaleRounds; ++round) {
    std::vector<double> num((k.p3_index.rows() - p3_first) * nt, 0.0), den(num.size(), 0.0);
    for (size_t t = 0; t < as.ids.size(); ++t)
      for (size_t p = 0; p < np; ++p) {
        const uint32_t p3 = k.p4_index.at(as.p4[t], p);
        if (p3 < p3_first) continue;
        const double f = double(as.scale[t]) * k.p4_scale.at(as.p4[t], p);
        for (size_t th = 0; th < nt; ++th) {
          const size_t at = t * planes + p * nt + th;
          num[(p3 - p3_first) * nt + th] += f * s.alpha[at];
          den[(p3 - p3_first) * nt + th] += f * f * s.beta[at];
        }
      }
    for (size_t i = 0; i < num.size(); ++i)
      if (den[i] > 0) k.p3_scale.data()[p3_first * nt + i] = non_negative(num[i] / den[i]);

    num.assign((k.p4_index.rows() - p4_first) * np, 0.0);
    den.assign(num.size(), 0.0);
    for (size_t t = 0; t < as.ids.size(); ++t) {
      if (as.p4[t] < p4_first) continue;
      const double s6 = as.scale[t];
      for (size_t p = 0; p < np; ++p) {
        const uint32_t p3 = k.p4_index.at(as.p4[t], p);
        double al = 0, be = 0;
        for (size_t th = 0; th < nt; ++th) {
          const double s3 = k.p3_scale.at(p3, th);
          al += s3 * s.alpha[t * planes + p * nt + th];
          be += s3 * s3 * s.beta[t * planes + p * nt + th];
        }
        num[(as.p4[t] - p4_first) * np + p] += s6 * al;
        den[(as.p4[t] - p4_first) * np + p] += s6 * s6 * be;
      }
    }
    for (size_t i = 0; i < num.size(); ++i)
      if (den[i] > 0) k.p4_scale.data()[p4_first * np + i] = non_negative(num[i] / den[i]);

    for (size_t t = 0; t < as.ids.size(); ++t) {
      double al = 0, be = 0;
      for (size_t p = 0; p < np; ++p) {
        const uint32_t p3 = k.p4_index.at(as.p4[t], p);
        const double s4 = k.p4_scale.at(as.p4[t], p);
        for (size_t th = 0; th < nt; ++th) {
          const double f = s4 * k.p3_scale.at(p3, th);
          al += f * s.alpha[t * planes + p * nt + th];
          be += f * f * s.beta[t * planes + p * nt + th];
        }
      }
      if (be > 0) as.scale[t] = non_negative(al / be);
    }
  }
}

}  // namespace

RefineStep refine_step(Codebooks& books, const CodebookSizes& first, Dynamic dyn, Assignment& assignment,
                       const TexelSource& source, size_t tile, const RefineMerge& merge, size_t threads,
                       const AssignTile& assign) {
  if (assignment.p4.size() != assignment.ids.size() || assignment.scale.size() != assignment.ids.size())
    throw InputError("refine_step: the assignment's ids, P4 entries and scales differ in number");
  if (books.grid.n_beta > 1024) throw InputError("refine_step: n_beta above 1024");
  if (!assign)  // else lower_sums checks each entry as it is assigned
    for (uint32_t e : assignment.p4)
      if (e >= books.p4_index.rows()) throw InputError("refine_step: a P4 index past the end of P4");
  const double values = double(assignment.ids.size()) * 3.0 * double(books.grid.samples());
  RefineStep step;
  if (assignment.ids.empty()) return step;
  tile = std::max<size_t>(tile, 1);
  LowerSums lower;
  const double error = lower_sums(books, first, dyn, assignment, source, tile, assign, lower);
  step.mse_before = error / values;
  const double budget = merge.budget * error;  // per kind of row merged
  update_luminance(books, first, lower, merge, budget, threads);
  update_chroma(books, first, lower, merge, budget, threads);
  if (merge.i2 > 0) merge_i2(books, first, lower, merge.i2, budget, threads);
  PlaneSums planes;
  plane_sums(books, dyn, assignment, source, tile, threads, planes);
  update_scales(books, first, assignment, planes);
  step.mse_after = plane_error(books, assignment, planes) / values;
  return step;
}

}  // namespace btfvq
