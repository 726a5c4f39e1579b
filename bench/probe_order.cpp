// Hand-run tool: bytes of a database's sections when the rows of its code-books are renumbered
// (an order of the rows is invisible to the decoded values).
//   probe_order DB
#include <algorithm>
#include <cstdio>
#include <numeric>
#include <map>
#include <cmath>
#include <string>

#include "pipeline/format/database.h"

using namespace btfvq;

namespace {
template <class T>
void permute(Table<T>& t, const std::vector<uint32_t>& to) {
  Table<T> out(t.cols());
  out.resize_rows(t.rows());
  for (size_t r = 0; r < t.rows(); ++r) std::copy(t.row(r), t.row(r) + t.cols(), out.row(to[r]));
  t = std::move(out);
}

void rewrite(Table<uint32_t>& t, const std::vector<uint32_t>& to, int column = -1) {
  for (size_t r = 0; r < t.rows(); ++r)
    for (size_t c = 0; c < t.cols(); ++c)
      if (column < 0 || size_t(column) == c) t.at(r, c) = to[t.at(r, c)];
}

// mode 0: first use; 1: (dominant column, first use); 2: (dominant column, uses desc)
std::vector<uint32_t> order_by_use(const Table<uint32_t>& parent, size_t n, int column, int mode) {
  std::vector<size_t> first(n, SIZE_MAX), uses(n, 0);
  std::vector<std::vector<size_t>> per_col(n, std::vector<size_t>(parent.cols(), 0));
  size_t pos = 0;
  for (size_t r = 0; r < parent.rows(); ++r)
    for (size_t c = 0; c < parent.cols(); ++c, ++pos) {
      if (column >= 0 && size_t(column) != c) continue;
      const uint32_t e = parent.at(r, c);
      first[e] = std::min(first[e], pos);
      uses[e]++;
      per_col[e][c]++;
    }
  std::vector<size_t> dom(n);
  for (size_t e = 0; e < n; ++e)
    dom[e] = size_t(std::max_element(per_col[e].begin(), per_col[e].end()) - per_col[e].begin());
  std::vector<uint32_t> old(n);
  std::iota(old.begin(), old.end(), 0);
  std::stable_sort(old.begin(), old.end(), [&](uint32_t a, uint32_t b) {
    if (mode >= 1 && dom[a] != dom[b]) return dom[a] < dom[b];
    if (mode == 2 && uses[a] != uses[b]) return uses[a] > uses[b];
    return first[a] < first[b];
  });
  std::vector<uint32_t> to(n);
  for (size_t i = 0; i < n; ++i) to[old[i]] = uint32_t(i);
  return to;
}

void report(const char* what, Database db) {
  db.versions.clear();
  const auto bytes = serialize_database(db);
  const DatabaseHead h = parse_head(bytes.data(), bytes.size());
  std::printf("%-28s total %9zu |", what, bytes.size());
  for (const auto& s : h.sections)
    std::printf(" %s %zu", s.kind == SectionKind::Codebook ? codebook_name(s.codebook) : "P6", size_t(s.length));
  std::printf("\n");
}

void apply_p4(Database& db, int mode) {
  Codebooks& k = db.codebooks;
  Table<uint32_t> p6(size_t(db.materials[0].width));
  const auto& idx = db.materials[0].p6_index;
  for (size_t r = 0; r < idx.size() / p6.cols(); ++r) {
    std::vector<uint32_t> v(idx.begin() + ptrdiff_t(r * p6.cols()), idx.begin() + ptrdiff_t((r + 1) * p6.cols()));
    p6.append(v.data());
  }
  (void)mode;
  auto to = order_by_use(p6, k.p4_index.rows(), -1, 0);
  permute(k.p4_index, to);
  permute(k.p4_scale, to);
  for (int32_t& e : db.materials[0].p6_index) e = int32_t(to[size_t(e)]);
}

void apply_p3(Database& db, int mode) {
  Codebooks& k = db.codebooks;
  auto to = order_by_use(k.p4_index, k.p3_index.rows(), -1, mode);
  permute(k.p3_index, to);
  permute(k.p3_scale, to);
  rewrite(k.p4_index, to);
}

void apply_m(Database& db, int mode) {
  Codebooks& k = db.codebooks;
  auto to = order_by_use(k.p3_index, k.m.rows(), -1, mode);
  permute(k.m, to);
  rewrite(k.p3_index, to);
}

void apply_p2(Database& db, int mode) {
  Codebooks& k = db.codebooks;
  auto to = order_by_use(k.m, k.p2_index.rows(), 0, mode);
  permute(k.p2_index, to);
  permute(k.p2_scale, to);
  rewrite(k.m, to, 0);
}

void apply_p1(Database& db, int mode) {
  Codebooks& k = db.codebooks;
  auto to = order_by_use(k.p2_index, k.p1.rows(), -1, mode);
  permute(k.p1, to);
  rewrite(k.p2_index, to);
}

}  // namespace

int main(int argc, char** argv) {
  std::setvbuf(stdout, nullptr, _IONBF, 0);
  if (argc < 2) return 2;
  const Database base = read_database(argv[1]);
  if (base.materials.size() != 1) return 3;
  report("as written", base);
  {
    const auto& t = base.codebooks.p4_index;
    const size_t n = base.codebooks.p3_index.rows();
    std::vector<std::vector<size_t>> pc(n, std::vector<size_t>(t.cols(), 0));
    std::vector<size_t> uses(n, 0);
    for (size_t r = 0; r < t.rows(); ++r)
      for (size_t c = 0; c < t.cols(); ++c) { pc[t.at(r, c)][c]++; uses[t.at(r, c)]++; }
    double dom = 0, h = 0, h0 = 0, total = double(t.rows() * t.cols());
    std::vector<double> colsum(t.cols(), 0);
    for (size_t e = 0; e < n; ++e) for (size_t c = 0; c < t.cols(); ++c) colsum[c] += double(pc[e][c]);
    for (size_t e = 0; e < n; ++e) {
      dom += double(*std::max_element(pc[e].begin(), pc[e].end()));
      if (uses[e]) h0 -= double(uses[e]) * std::log2(double(uses[e]) / total);
      for (size_t c = 0; c < t.cols(); ++c) if (pc[e][c]) h -= double(pc[e][c]) * std::log2(double(pc[e][c]) / colsum[c]);
    }
    size_t used = 0; for (size_t u : uses) used += u > 0;
    std::printf("P4->P3: %zu refs, %zu of %zu entries used, in dominant column %.3f, H0 %.0f B, H|col %.0f B\n", size_t(total), used, n, dom / total, h0 / 8, h / 8);
  }
  for (int mode = 0; mode < 3; ++mode) {
    Database d = base;
    apply_p3(d, mode);
    report(("P3 mode " + std::to_string(mode)).c_str(), d);
  }
  {
    Database d = base;
    apply_p4(d, 0);
    report("P4 first use", d);
    for (int mode = 0; mode < 3; ++mode) {
      Database e = d;
      apply_p3(e, mode);
      report(("P4 + P3 mode " + std::to_string(mode)).c_str(), e);
      apply_m(e, mode);
      report(("P4 + P3 + M mode " + std::to_string(mode)).c_str(), e);
      apply_p2(e, 0);
      report(("... + P2 first use"), e);
      apply_p1(e, 0);
      report(("... + P1 first use"), e);
    }
  }
}
