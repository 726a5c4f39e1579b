#include "pipeline/decode/reconstruct.h"

#include <algorithm>
#include <cmath>

#include "pipeline/decode/decoder.h"
#include <btfvq/error.h>
#include "pipeline/util/parallel.h"

namespace btfvq {

namespace {

const Material& find_material(const Database& db, const std::string& name, size_t* index) {
  for (size_t i = 0; i < db.materials.size(); ++i)
    if (db.materials[i].name == name) {
      *index = i;
      return db.materials[i];
    }
  throw NotFoundError("no material '" + name + "' in the database");
}

// Decoded value of every P4 entry this material uses, for one direction pair.
void decode_p4_table(const Decoder& decoder, const Material& mat, const std::vector<uint32_t>& used,
                     const Direction& light, const Direction& view, std::vector<Rgb>& table) {
  const bool hdr = mat.dynamic == Dynamic::HDR;
  for (uint32_t p4 : used) table[p4] = decoder.evaluate_p4(p4, hdr, light, view);
}

std::vector<uint32_t> used_p4_entries(const Material& mat, size_t p4_rows) {
  std::vector<char> seen(p4_rows, 0);
  std::vector<uint32_t> used;
  for (int32_t i : mat.p6_index)
    if (i >= 0 && !seen[size_t(i)]) {
      seen[size_t(i)] = 1;
      used.push_back(uint32_t(i));
    }
  return used;
}

// The column of one (view, light) pair, from the P4 table decoded for its directions.
void fill_pair(const Material& mat, const std::vector<Rgb>& table, size_t pair, MeasuredSample& out) {
  const size_t pairs = out.pair_count(), texels = out.texel_count();
  for (size_t t = 0; t < texels; ++t) {
    const int32_t p4 = mat.p6_index[t];
    const Rgb c = p4 < 0 ? Rgb{} : table[size_t(p4)];
    const float s = p4 < 0 ? 0.0f : mat.p6_scale[t];
    const float rgb[3] = {c.r * s, c.g * s, c.b * s};
    const size_t base = (t * pairs + pair) * 3;
    for (int ch = 0; ch < 3; ++ch) {
      if (mat.dynamic == Dynamic::LDR)
        out.ldr_data()[base + size_t(ch)] = uint8_t(std::clamp(std::lround(rgb[ch]), 0L, 255L));
      else
        out.hdr_data()[base + size_t(ch)] = rgb[ch];
    }
  }
}

}  // namespace

std::vector<float> decode_image(const Database& db, const std::string& material, const Direction& light,
                                const Direction& view) {
  size_t index = 0;
  const Material& mat = find_material(db, material, &index);
  const Decoder decoder(db);
  const auto used = used_p4_entries(mat, db.codebooks.p4_index.rows());
  std::vector<Rgb> table(db.codebooks.p4_index.rows());
  decode_p4_table(decoder, mat, used, light, view, table);
  std::vector<float> out(mat.p6_index.size() * 3, 0.0f);
  for (size_t t = 0; t < mat.p6_index.size(); ++t) {
    if (mat.p6_index[t] < 0) continue;
    const Rgb& v = table[size_t(mat.p6_index[t])];
    const float s = mat.p6_scale[t];
    out[3 * t] = v.r * s;
    out[3 * t + 1] = v.g * s;
    out[3 * t + 2] = v.b * s;
  }
  return out;
}

MeasuredSample reconstruct_sample(const Database& db, const std::string& material, const MeasuredSample& geometry,
                                  int threads) {
  size_t index = 0;
  const Material& mat = find_material(db, material, &index);
  std::vector<std::vector<Direction>> lights;
  for (size_t v = 0; v < geometry.view_count(); ++v) lights.push_back(geometry.lights(v));
  MeasuredSample out(mat.width, mat.height, geometry.views(), lights, mat.dynamic);
  const Decoder decoder(db);
  const auto used = used_p4_entries(mat, db.codebooks.p4_index.rows());

  // Pairs are independent: each worker takes the next (view, light) pair and fills its column from
  // a P4 table of its own, reused pair after pair (it is as long as the code-book).
  std::vector<std::pair<size_t, size_t>> order;
  for (size_t v = 0; v < out.view_count(); ++v)
    for (size_t l = 0; l < out.lights(v).size(); ++l) order.emplace_back(v, l);
  const ParallelOptions options{.threads = size_t(std::max(threads, 1)), .grain = 1};
  std::vector<std::vector<Rgb>> tables(parallel_slots(order.size(), options),
                                       std::vector<Rgb>(db.codebooks.p4_index.rows()));
  parallel_for(0, order.size(), [&](size_t first, size_t last, size_t slot) {
    for (size_t k = first; k < last; ++k) {
      const auto [v, l] = order[k];
      decode_p4_table(decoder, mat, used, out.lights(v)[l], out.views()[v], tables[slot]);
      fill_pair(mat, tables[slot], out.pair_index(v, l), out);
    }
  }, options);
  return out;
}

MeasuredSample reconstruct_bonn(const Database& db, const std::string& material, int threads) {
  const Material* mat = db.find(material);
  if (!mat) throw NotFoundError("no material '" + material + "' in the database");
  return reconstruct_sample(db, material, make_bonn_sample(1, 1, mat->dynamic), threads);
}

}  // namespace btfvq
