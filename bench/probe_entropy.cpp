// Hand-run tool: builds (or reuses) default-setting databases of the synthetic presets and the real
// BTFBASE imports, then prints per section kind the bytes raw packed, with zstd, and statistics of the
// fields that guide the entropy coder.
//   probe_entropy CACHE_DIR SIZE TESTDATA_DIR
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <string>

#include "pipeline/io/btfbase.h"
#include "pipeline/encode/compress.h"
#include "pipeline/format/database.h"
#include "pipeline/io/synthetic.h"
#include "pipeline/format/packing.h"

using namespace btfvq;

namespace {

double entropy(const std::map<int64_t, size_t>& h) {
  size_t n = 0;
  for (auto& [k, c] : h) n += c;
  double e = 0;
  for (auto& [k, c] : h) e -= double(c) * std::log2(double(c) / double(n));
  return e / 8;  // bytes
}

void stats(const char* what, const std::vector<int64_t>& v, size_t cols, int bits) {
  std::map<int64_t, size_t> h0, hd, hdu;
  size_t eqL = 0, eqU = 0, eqL1 = 0;
  for (size_t i = 0; i < v.size(); ++i) {
    h0[v[i]]++;
    const size_t c = i % cols;
    const int64_t L = c > 0 ? v[i - 1] : -1, U = i >= cols ? v[i - cols] : -1;
    eqL += v[i] == L;
    eqU += v[i] == U;
    eqL1 += v[i] == L + 1;
    hd[c > 0 ? v[i] - L : v[i]]++;
    hdu[i >= cols ? v[i] - U : v[i]]++;
  }
  std::printf("  %-14s n=%7zu cols=%3zu bits=%2d packed=%8.0f H0=%8.0f Hleft=%8.0f Hup=%8.0f  =L %.2f =U %.2f =L+1 %.2f\n",
              what, v.size(), cols, bits, double(v.size() * bits) / 8, entropy(h0), entropy(hd), entropy(hdu),
              double(eqL) / double(v.size()), double(eqU) / double(v.size()), double(eqL1) / double(v.size()));
}

template <class T>
std::vector<int64_t> col(const Table<T>& t, int c) {
  std::vector<int64_t> v;
  for (size_t r = 0; r < t.rows(); ++r)
    for (size_t k = 0; k < t.cols(); ++k)
      if (c < 0 || int(k) == c) v.push_back(int64_t(t.at(r, k)));
  return v;
}

void probe(const std::string& name, Database db) {
  db.versions.clear();  // publish afresh with each setting (quantization is idempotent)
  PackSettings raw, zstd;
  raw.zstd_level = 0;
  raw.range_coding = zstd.range_coding = false;
  const auto a = serialize_database(db, raw), b = serialize_database(db, zstd), c = serialize_database(db);
  {
    const Database x = parse_database(c), y = parse_database(a);
    if (!(x.codebooks == y.codebooks && x.materials == y.materials)) std::printf("MISMATCH\n");
  }
  std::printf("%s: raw %zu zstd %zu (%+.1f%%) rc %zu (%+.1f%%)\n", name.c_str(), a.size(), b.size(),
              100.0 * (double(a.size()) / double(b.size()) - 1), c.size(), 100.0 * (double(a.size()) / double(c.size()) - 1));
  const DatabaseHead ha = parse_head(a.data(), a.size()), hb = parse_head(b.data(), b.size()), hc = parse_head(c.data(), c.size());
  for (size_t i = 0; i < ha.sections.size(); ++i) {
    const auto& e = hc.sections[i];
    if (e.encoding == 2) {
      // Per field: model and stream bytes (layout of docs/format.md, encoding 2).
      const uint8_t* p = c.data() + e.offset;
      size_t at = e.kind == SectionKind::Material ? 2 + (p[0] | (p[1] << 8)) + 17 : 16;
      const size_t nf = e.kind == SectionKind::Material ? 2
                        : (e.codebook == CodebookId::P1 || e.codebook == CodebookId::C || e.codebook == CodebookId::I1 ||
                           e.codebook == CodebookId::I2) ? 1 : 2;
      bool values[2] = {e.codebook == CodebookId::P1 || e.codebook == CodebookId::C, true};
      if (e.codebook == CodebookId::M) values[1] = false;
      if (e.kind == SectionKind::Material) values[0] = false;
      std::printf("   ");
      for (size_t f = 0; f < nf; ++f) {
        at += values[f] ? 10 : 1;
        const int model = p[at++];
        uint64_t len = 0;
        if (f + 1 < nf) {
          for (int sh = 0;; sh += 7) { const uint8_t b = p[at++]; len |= uint64_t(b & 0x7F) << sh; if (!(b & 0x80)) break; }
        } else {
          len = e.length - at;
        }
        std::printf(" field %zu model %2d (flags %d lit %d pred %d col %d) %llu bytes;", f, model, model & 1, (model >> 1) & 3,
                    (model >> 3) & 3, (model >> 5) & 1, (unsigned long long)len);
        at += len;
      }
      std::printf("\n");
    }
    std::printf("  section %-10s raw %8llu zstd %8llu best %8llu (enc %d)\n",
                ha.sections[i].kind == SectionKind::Codebook ? codebook_name(ha.sections[i].codebook) : "material",
                (unsigned long long)ha.sections[i].length, (unsigned long long)hb.sections[i].length,
                (unsigned long long)hc.sections[i].length, hc.sections[i].encoding);
  }
  // Field statistics on the codes (scales as their 8-bit codes via the value stored).
  Database q = db;
  publish_version(q);
  const auto& k = q.codebooks;
  auto bits = [](size_t s) { return s <= 2 ? 1 : int(std::ceil(std::log2(double(s)))); };
  stats("I1", col(k.i1, -1), k.i1.cols(), bits(k.c.rows()));
  stats("I2", col(k.i2, -1), k.i2.cols(), bits(k.i1.rows()));
  stats("P2 idx", col(k.p2_index, -1), k.p2_index.cols(), bits(k.p1.rows()));
  stats("M p2", col(k.m, 0), 1, bits(k.p2_index.rows()));
  stats("M i2", col(k.m, 1), 1, bits(k.i2.rows()));
  stats("P3 idx", col(k.p3_index, -1), k.p3_index.cols(), bits(k.m.rows()));
  stats("P4 idx", col(k.p4_index, -1), k.p4_index.cols(), bits(k.p3_index.rows()));
  // Scales: rank of each value among the distinct values = its code, up to a monotone relabelling.
  auto codes = [](const std::vector<float>& f) {
    std::map<float, int64_t> rank;
    for (float x : f) rank[x] = 0;
    int64_t r = 0;
    for (auto& [x, c] : rank) c = r++;
    std::vector<int64_t> v;
    for (float x : f) v.push_back(rank[x]);
    return v;
  };
  stats("P2 scale", codes(k.p2_scale.data()), k.p2_scale.cols(), 8);
  stats("P3 scale", codes(k.p3_scale.data()), k.p3_scale.cols(), 8);
  stats("P4 scale", codes(k.p4_scale.data()), k.p4_scale.cols(), 8);
  stats("P1", codes(k.p1.data()), k.p1.cols(), 8);
  stats("C", codes(k.c.data()), k.c.cols(), 16);
  for (const Material& m : q.materials) {
    std::vector<int64_t> idx(m.p6_index.begin(), m.p6_index.end());
    stats("P6 idx", idx, size_t(m.width), bits(k.p4_index.rows() + 1));
    stats("P6 scale", codes(m.p6_scale), size_t(m.width), 8);
  }
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 4) return 2;
  const std::filesystem::path cache = argv[1];
  const int size = std::atoi(argv[2]);
  const std::string testdata = argv[3];
  std::filesystem::create_directories(cache);
  for (const auto& p : synthetic_presets()) {
    const auto path = cache / (p.name + "-" + std::to_string(size) + ".btfdb");
    if (!std::filesystem::exists(path)) {
      SynthOptions o;
      o.preset = p.name;
      o.size = size;
      Database db;
      compress_material(db, synthesize(o), p.name, {});
      PackSettings zstd_only;  // independent of changes to encoding 2
      zstd_only.range_coding = false;
      write_database(db, path.string(), zstd_only);
    }
    probe(p.name, read_database(path.string()));
  }
  for (const char* real : {"alu", "proposte"}) {
    if (argc > 4) break;
    try {
      probe(real, import_btfbase(testdata + "/btfbase/" + real));
    } catch (const std::exception& e) {
      std::printf("%s: %s\n", real, e.what());
    }
  }
  return 0;
}
