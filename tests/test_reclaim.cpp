// reclaim_unreachable (pipeline/codebook.h): unpublished rows no P6 reaches are removed and the rest
// renumbered; what every material decodes to does not change, and published rows stay as they are.
#include <doctest/doctest.h>

#include "pipeline/decode/decoder.h"
#include "pipeline/encode/compress.h"
#include "pipeline/format/database.h"
#include "pipeline/io/synthetic.h"

using namespace btfvq;

namespace {

MeasuredSample synth(const std::string& preset, uint64_t seed) {
  SynthOptions o;
  o.preset = preset;
  o.size = 8;
  o.seed = seed;
  return synthesize(o);
}

std::vector<Rgb> decode_all(const Database& db) {
  std::vector<DecodeQuery> q;
  const auto& dirs = bonn81();
  for (uint32_t m = 0; m < db.materials.size(); ++m)
    for (int y = 0; y < db.materials[m].height; ++y)
      for (int x = 0; x < db.materials[m].width; ++x)
        for (size_t d = 0; d < dirs.size(); d += 7) q.push_back({m, x, y, dirs[d], dirs[(d * 5 + 3) % dirs.size()]});
  return Decoder(db).decode_reference(q);
}

bool same(const std::vector<Rgb>& a, const std::vector<Rgb>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (a[i].r != b[i].r || a[i].g != b[i].g || a[i].b != b[i].b) return false;
  return true;
}

// Appends rows nothing references, at every level (what a rejected composition leaves behind).
void append_garbage(Codebooks& k) {
  const std::vector<float> p1(k.p1.cols(), 1.0f / float(k.p1.cols())), c = {120.0f, 130.0f};
  const uint32_t e1 = k.p1.append(p1.data()), ec = k.c.append(c.data());
  const std::vector<uint32_t> i1(k.i1.cols(), ec), p2i(k.p2_index.cols(), e1);
  const std::vector<float> p2s(k.p2_scale.cols(), 50.0f);
  const uint32_t ei1 = k.i1.append(i1.data());
  const std::vector<uint32_t> i2(k.i2.cols(), ei1);
  const uint32_t ei2 = k.i2.append(i2.data());
  const uint32_t ep2 = k.p2_index.append(p2i.data());
  k.p2_scale.append(p2s.data());
  const uint32_t m[2] = {ep2, ei2};
  const uint32_t em = k.m.append(m);
  const std::vector<uint32_t> p3i(k.p3_index.cols(), em);
  const std::vector<float> ones3(k.p3_scale.cols(), 1.0f), ones4(k.p4_scale.cols(), 1.0f);
  const uint32_t ep3 = k.p3_index.append(p3i.data());
  k.p3_scale.append(ones3.data());
  const std::vector<uint32_t> p4i(k.p4_index.cols(), ep3);
  k.p4_index.append(p4i.data());
  k.p4_scale.append(ones4.data());
}

}  // namespace

TEST_CASE("a compressed material's code-books hold only rows its P6 reaches") {
  Database db;
  const CompressReport r = compress_material(db, synth("leather", 1), "leather", {});
  const Database reclaimed = db;
  const ReclaimReport again = reclaim_unreachable(db);
  CHECK(db == reclaimed);  // nothing to remove and P4 already in first-use order
  for (CodebookId id : kAllCodebooks) {
    CHECK(again.removed[id] == 0);
    CHECK(again.reachable[id] == CodebookSizes::of(db.codebooks)[id]);
    CHECK(r.json["encoder"]["reachable"][codebook_name(id)].get<size_t>() == CodebookSizes::of(db.codebooks)[id]);
  }
}

TEST_CASE("unreachable unpublished rows are removed; decoding and published rows do not change") {
  Database db;
  compress_material(db, synth("leather", 1), "leather", {});
  publish_version(db);
  const Codebooks published = db.codebooks;
  append_garbage(db.codebooks);  // unreachable rows past the published version
  compress_material(db, synth("wood", 2), "wood", {});
  append_garbage(db.codebooks);
  const CodebookSizes before = CodebookSizes::of(db.codebooks);
  const std::vector<Rgb> decoded = decode_all(db);

  const ReclaimReport r = reclaim_unreachable(db);
  db.validate();
  CHECK(same(decode_all(db), decoded));
  const CodebookSizes after = CodebookSizes::of(db.codebooks);
  for (CodebookId id : kAllCodebooks) {
    CHECK(r.removed[id] >= 1);  // at least the second garbage row of every code-book
    CHECK(after[id] == before[id] - r.removed[id]);
    CHECK(r.reachable[id] == after[id]);
  }
  // Published rows keep their index and content.
  auto prefix = [](const auto& now, const auto& then) {
    return std::equal(then.data().begin(), then.data().end(), now.data().begin());
  };
  CHECK(prefix(db.codebooks.p1, published.p1));
  CHECK(prefix(db.codebooks.c, published.c));
  CHECK(prefix(db.codebooks.i1, published.i1));
  CHECK(prefix(db.codebooks.i2, published.i2));
  CHECK(prefix(db.codebooks.p2_index, published.p2_index));
  CHECK(prefix(db.codebooks.p2_scale, published.p2_scale));
  CHECK(prefix(db.codebooks.m, published.m));
  CHECK(prefix(db.codebooks.p3_index, published.p3_index));
  CHECK(prefix(db.codebooks.p4_index, published.p4_index));
  CHECK(prefix(db.codebooks.p4_scale, published.p4_scale));
  // Unpublished P4 rows are numbered in the order the materials' P6 first reach them.
  uint32_t next = uint32_t(published.p4_index.rows());
  size_t out_of_order = 0;
  for (const Material& mat : db.materials)
    for (int32_t e : mat.p6_index)
      if (e >= int32_t(next)) out_of_order += e != int32_t(next++);
  CHECK(next == after[CodebookId::P4]);
  CHECK(out_of_order == 0);
  // And the file still writes and reads back to the same values.
  const Database back = parse_database(serialize_database(db), "memory");
  quantize_new_rows(db);
  CHECK(same(decode_all(back), decode_all(db)));
}
