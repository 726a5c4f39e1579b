#include "pipeline/format/database.h"

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>

#include <zstd.h>

#include <btfvq/error.h>
#include "pipeline/format/packing.h"
#include "pipeline/format/section_coding.h"
#include "pipeline/util/atomic_file.h"

namespace btfvq {

namespace {

constexpr char kMagic[8] = {'B', 'T', 'F', 'V', 'Q', 'D', 'B', '1'};
constexpr uint32_t kFormatVersion = 1;
constexpr size_t kVersionRecordBytes = 52;
// A zstd section may expand at most this much (plus kZstdSlack bytes): a writer stores such a section
// raw instead, and a reader refuses to allocate more for a section (decompression bombs).
constexpr uint64_t kZstdMaxRatio = 1024;
constexpr uint64_t kZstdSlack = 4096;
constexpr size_t kEntryFixedBytes = 44;
constexpr uint16_t kNoCodebook = 0xFFFF;
constexpr int kMaxGridCount = 4096;

// The value codings of a version, in the order they are stored in a version record.
ValueCoding* codings(VersionMark& v, int k) {
  ValueCoding* all[6] = {&v.p1_values, &v.c_values, &v.p2_scale, &v.p3_scale, &v.p4_scale, &v.p6_scale};
  return all[k];
}

// One stored field of a code-book chunk: an index column (or all columns) into `target`, or floats.
struct Field {
  Table<uint32_t>* index = nullptr;
  int column = -1;  // -1: all columns of the row; otherwise one column
  CodebookId target = CodebookId::P1;
  Table<float>* values = nullptr;
  ValueCoding VersionMark::*coding = nullptr;
  double PackSettings::*error = nullptr;  // the values' allowed relative error, if any (quantize_values)
};

std::vector<Field> fields_of(Codebooks& k, CodebookId id) {
  switch (id) {
    case CodebookId::P1: return {{nullptr, -1, {}, &k.p1, &VersionMark::p1_values}};
    case CodebookId::C: return {{nullptr, -1, {}, &k.c, &VersionMark::c_values}};
    case CodebookId::I1: return {{&k.i1, -1, CodebookId::C}};
    case CodebookId::I2: return {{&k.i2, -1, CodebookId::I1}};
    case CodebookId::P2:
      return {{&k.p2_index, -1, CodebookId::P1}, {nullptr, -1, {}, &k.p2_scale, &VersionMark::p2_scale}};
    case CodebookId::M: return {{&k.m, 0, CodebookId::P2}, {&k.m, 1, CodebookId::I2}};
    case CodebookId::P3:
      return {{&k.p3_index, -1, CodebookId::M}, {nullptr, -1, {}, &k.p3_scale, &VersionMark::p3_scale}};
    case CodebookId::P4:
      return {{&k.p4_index, -1, CodebookId::P3},
              {nullptr, -1, {}, &k.p4_scale, &VersionMark::p4_scale, &PackSettings::p4_scale_error}};
  }
  return {};
}

size_t table_rows(Codebooks& k, CodebookId id) {
  const Field f = fields_of(k, id).front();
  return f.index ? f.index->rows() : f.values->rows();
}

VersionMark current_sizes(Database& db) {
  VersionMark v;
  for (CodebookId id : kAllCodebooks) v.rows[id] = table_rows(db.codebooks, id);
  v.materials = db.materials.size();
  return v;
}

const VersionMark& last_mark(const Database& db) {
  static const VersionMark empty;
  return db.versions.empty() ? empty : db.versions.back();
}

std::string section_name(CodebookId id, uint32_t version) {
  return std::string("code-book ") + codebook_name(id) + " chunk of version " + std::to_string(version);
}

// Shape and version checks that the format relies on; problems are the caller's (InputError).
void check_writable(Database& db) {
  Codebooks& k = db.codebooks;
  k.grid.validate();
  for (CodebookId id : kAllCodebooks)
    for (const Field& f : fields_of(k, id)) {
      const size_t cols = f.index ? f.index->cols() : f.values->cols();
      const size_t rows = f.index ? f.index->rows() : f.values->rows();
      const size_t want_cols = f.column >= 0 ? 2
                               : id == CodebookId::C ? 2
                               : (id == CodebookId::P1 || id == CodebookId::I1) ? size_t(k.grid.n_beta)
                               : (id == CodebookId::I2 || id == CodebookId::P2) ? size_t(k.grid.n_alpha)
                               : id == CodebookId::P3 ? size_t(k.grid.n_theta_v)
                                                      : size_t(k.grid.n_phi_v);
      if (cols != want_cols)
        throw InputError(std::string("code-book ") + codebook_name(id) + " has " + std::to_string(cols) +
                         " columns, the grid needs " + std::to_string(want_cols));
      if (rows != table_rows(k, id))
        throw InputError(std::string("code-book ") + codebook_name(id) + ": index and scale tables differ in rows");
      if (rows > 0xFFFFFFFFu) throw InputError(std::string("code-book ") + codebook_name(id) + " has too many rows");
    }
  db.validate();
  const VersionMark now = current_sizes(db);
  VersionMark prev;
  for (size_t v = 0; v < db.versions.size(); ++v) {
    const VersionMark& mark = db.versions[v];
    for (CodebookId id : kAllCodebooks)
      if (mark.rows[id] < prev.rows[id] || mark.rows[id] > now.rows[id])
        throw InputError("version " + std::to_string(v + 1) + " mark of code-book " + codebook_name(id) +
                         " is inconsistent with the code-book");
    if (mark.materials < prev.materials || mark.materials > now.materials)
      throw InputError("version " + std::to_string(v + 1) + " mark of the material count is inconsistent");
    prev = mark;
  }
  std::set<std::string> names;
  for (const Material& m : db.materials) {
    if (m.name.empty() || m.name.size() > 0xFFFF) throw InputError("material name '" + m.name + "' is empty or too long");
    if (!names.insert(m.name).second) throw InputError("two materials are named '" + m.name + "'");
    if (m.width <= 0 || m.height <= 0) throw InputError("material '" + m.name + "' has no texels");
  }
}

bool has_unpublished(Database& db) {
  const VersionMark now = current_sizes(db);
  const VersionMark& last = last_mark(db);
  if (db.versions.empty()) return true;
  for (CodebookId id : kAllCodebooks)
    if (now.rows[id] != last.rows[id]) return true;
  return now.materials != last.materials;
}

VersionMark next_codings(const Database& db, const PackSettings& s) {
  bool hdr = false;
  for (const Material& m : db.materials) hdr = hdr || m.dynamic == Dynamic::HDR;
  VersionMark v;
  v.p1_values = s.p1_values;
  v.c_values = s.c_values;
  v.p2_scale = hdr ? s.p2_scale_hdr : s.p2_scale;
  v.p3_scale = s.p3_scale;
  v.p4_scale = s.p4_scale;
  v.p6_scale = s.p6_scale;
  if (s.zstd_level < 0 || s.zstd_level > ZSTD_maxCLevel())
    throw InputError("zstd level " + std::to_string(s.zstd_level) + " is out of range 0.." + std::to_string(ZSTD_maxCLevel()));
  v.zstd_level = uint8_t(s.zstd_level);
  v.range_coding = s.range_coding ? 1 : 0;
  return v;
}

// Index values of one field for rows [r0, r1), in row-major order.
std::vector<uint32_t> gather(const Field& f, size_t r0, size_t r1) {
  if (f.column < 0) return {f.index->row(r0), f.index->row(r0) + (r1 - r0) * f.index->cols()};
  std::vector<uint32_t> v;
  for (size_t r = r0; r < r1; ++r) v.push_back(f.index->at(r, size_t(f.column)));
  return v;
}

std::vector<uint8_t> encode_chunk(Codebooks& k, CodebookId id, uint32_t version, const VersionMark& prev,
                                  const VersionMark& mark) {
  const size_t r0 = prev.rows[id], r1 = mark.rows[id];
  const std::string what = section_name(id, version);
  std::vector<uint8_t> out;
  ByteWriter w(out);
  w.u16(uint16_t(id));
  w.u16(0);
  w.u32(version);
  w.u32(uint32_t(r0));
  w.u32(uint32_t(r1 - r0));
  for (const Field& f : fields_of(k, id)) {
    if (f.index) {
      const auto v = gather(f, r0, r1);
      const size_t limit = mark.rows[f.target];
      for (size_t i = 0; i < v.size(); ++i)
        if (v[i] >= limit)
          throw InputError(what + ": index " + std::to_string(v[i]) + " in row " +
                           std::to_string(r0 + i / (f.column < 0 ? f.index->cols() : 1)) + " points past " +
                           codebook_name(f.target) + " as published in that version (" + std::to_string(limit) +
                           " entries)");
      write_indices(w, v.data(), v.size(), index_bits(limit));
    } else {
      write_values(w, f.values->row(r0), (r1 - r0) * f.values->cols(), mark.*f.coding, what);
    }
  }
  return out;
}

std::vector<uint8_t> encode_material(const Material& m, uint32_t version, const VersionMark& mark) {
  std::vector<uint8_t> out;
  ByteWriter w(out);
  w.u16(uint16_t(m.name.size()));
  w.bytes(m.name.data(), m.name.size());
  w.u32(uint32_t(m.width));
  w.u32(uint32_t(m.height));
  w.u8(m.dynamic == Dynamic::HDR ? 1 : 0);
  w.u64(m.raw_bytes);
  const uint64_t limit = uint64_t(mark.rows[CodebookId::P4]) + 1;
  std::vector<uint32_t> shifted(m.p6_index.size());
  for (size_t i = 0; i < shifted.size(); ++i) {
    if (uint64_t(int64_t(m.p6_index[i]) + 1) >= limit)
      throw InputError("material '" + m.name + "' (version " + std::to_string(version) + "): P6 index " +
                       std::to_string(m.p6_index[i]) + " points past P4 as published in that version");
    shifted[i] = uint32_t(m.p6_index[i] + 1);
  }
  write_indices(w, shifted.data(), shifted.size(), index_bits(limit));
  write_values(w, m.p6_scale.data(), m.p6_scale.size(), mark.p6_scale, "material '" + m.name + "' P6 scales");
  return out;
}

// The section sequence that a list of versions implies: for each version its code-book chunks in
// CodebookId order (those that grew), then the materials it added.
struct Expected {
  SectionKind kind;
  uint32_t version;
  CodebookId codebook;
  size_t material;  // index, kind Material
};

std::vector<Expected> expected_sections(const std::vector<VersionMark>& versions) {
  std::vector<Expected> e;
  VersionMark prev;
  for (size_t v = 0; v < versions.size(); ++v) {
    for (CodebookId id : kAllCodebooks)
      if (versions[v].rows[id] > prev.rows[id]) e.push_back({SectionKind::Codebook, uint32_t(v + 1), id, 0});
    for (size_t m = prev.materials; m < versions[v].materials; ++m)
      e.push_back({SectionKind::Material, uint32_t(v + 1), CodebookId::P1, m});
    prev = versions[v];
  }
  return e;
}

std::string describe(const SectionEntry& s, size_t i) {
  std::string d = "section " + std::to_string(i) + " (";
  d += s.kind == SectionKind::Codebook ? section_name(s.codebook, s.version)
                                       : "material '" + s.material + "' of version " + std::to_string(s.version);
  return d + ")";
}

void decode_chunk(ByteReader& r, Codebooks& k, CodebookId id, uint32_t version, const VersionMark& prev,
                  const VersionMark& mark) {
  const size_t r0 = prev.rows[id], r1 = mark.rows[id];
  if (r.u16() != uint16_t(id) || r.u16() != 0 || r.u32() != version) r.fail("code-book id or version differs from the table");
  if (r.u32() != r0 || r.u32() != r1 - r0)
    r.fail("rows differ from the version record (expected rows " + std::to_string(r0) + ".." + std::to_string(r1) + ")");
  for (const Field& f : fields_of(k, id)) {
    if (f.index) {
      const size_t per_row = f.column < 0 ? f.index->cols() : 1;
      const size_t limit = mark.rows[f.target];
      const auto v = read_indices(r, (r1 - r0) * per_row, index_bits(limit), limit,
                                  std::string("indices into ") + codebook_name(f.target));
      if (f.index->rows() < r1) f.index->resize_rows(r1);
      if (f.column < 0) std::copy(v.begin(), v.end(), f.index->row(r0));
      else
        for (size_t i = 0; i < v.size(); ++i) f.index->at(r0 + i, size_t(f.column)) = v[i];
    } else {
      const auto v = read_values(r, (r1 - r0) * f.values->cols(), "values");
      f.values->resize_rows(r1);
      std::copy(v.begin(), v.end(), f.values->row(r0));
    }
  }
}

Material decode_material(ByteReader& r, const std::string& table_name, const VersionMark& mark) {
  Material m;
  const uint16_t len = r.u16();
  const uint8_t* name = r.bytes(len);
  m.name.assign(reinterpret_cast<const char*>(name), len);
  if (m.name != table_name) r.fail("material name '" + m.name + "' differs from the section table");
  const uint32_t w = r.u32(), h = r.u32();
  if (w == 0 || h == 0 || w > 0x7FFFFFFFu || h > 0x7FFFFFFFu) r.fail("invalid size " + std::to_string(w) + " x " + std::to_string(h));
  m.width = int(w);
  m.height = int(h);
  const uint8_t dyn = r.u8();
  if (dyn > 1) r.fail("unknown dynamic range " + std::to_string(dyn));
  m.dynamic = dyn ? Dynamic::HDR : Dynamic::LDR;
  m.raw_bytes = r.u64();
  const uint64_t n = uint64_t(w) * h;
  const uint64_t limit = uint64_t(mark.rows[CodebookId::P4]) + 1;
  const auto idx = read_indices(r, n, index_bits(limit), limit, "P6 indices");
  m.p6_index.resize(n);
  for (size_t i = 0; i < n; ++i) {
    if (idx[i] > 0x7FFFFFFFu) r.fail("P6 index " + std::to_string(idx[i]) + " does not fit the model");
    m.p6_index[i] = int32_t(idx[i]) - 1;
  }
  m.p6_scale = read_values(r, n, "P6 scales");
  return m;
}

struct Stored {
  uint16_t encoding = 0;
  std::vector<uint8_t> bytes;
};

// The fields of a section (for encoding 2), from the section kind and its header bytes at p (raw or
// stored: encoding 2 keeps the header verbatim).
SectionShape section_shape(const SectionEntry& e, const AngularGrid& g, const uint8_t* p, size_t n,
                           const std::string& where) {
  ByteReader r(p, n, where);
  SectionShape s;
  if (e.kind == SectionKind::Material) {
    const uint16_t len = r.u16();
    r.bytes(len);
    const uint64_t w = r.u32(), h = r.u32();
    r.u8();
    r.u64();
    s.header_bytes = r.position();
    s.fields = {{FieldShape::Index, w * h, std::max<uint64_t>(w, 1)}, {FieldShape::Values, w * h, std::max<uint64_t>(w, 1)}};
    return s;
  }
  r.bytes(12);
  const uint64_t rows = r.u32();
  s.header_bytes = r.position();
  const uint64_t cols = e.codebook == CodebookId::C                                           ? 2
                        : (e.codebook == CodebookId::P1 || e.codebook == CodebookId::I1)      ? uint64_t(g.n_beta)
                        : (e.codebook == CodebookId::I2 || e.codebook == CodebookId::P2)      ? uint64_t(g.n_alpha)
                        : e.codebook == CodebookId::P3                                        ? uint64_t(g.n_theta_v)
                        : e.codebook == CodebookId::P4                                        ? uint64_t(g.n_phi_v)
                                                                                              : 1;
  switch (e.codebook) {
    case CodebookId::P1:
    case CodebookId::C: s.fields = {{FieldShape::Values, rows * cols, cols}}; break;
    case CodebookId::I1:
    case CodebookId::I2: s.fields = {{FieldShape::Index, rows * cols, cols}}; break;
    case CodebookId::M: s.fields = {{FieldShape::Index, rows, 1}, {FieldShape::Index, rows, 1}}; break;
    default: s.fields = {{FieldShape::Index, rows * cols, cols}, {FieldShape::Values, rows * cols, cols}};
  }
  return s;
}

bool within_bomb_bound(uint64_t raw, uint64_t stored) { return raw <= kZstdMaxRatio * stored + kZstdSlack; }

// The smallest of encoding 0 (raw packed), 1 (zstd at `level`, if > 0) and 2 (modelled range coder,
// if `range_coding`), each only within the expansion bound; ties go to the lower encoding.
Stored encode_section(std::vector<uint8_t> raw, const SectionEntry& e, const AngularGrid& g, int level,
                      bool range_coding) {
  Stored best{0, raw};
  if (raw.empty()) return best;
  if (level > 0) {
    std::vector<uint8_t> z(ZSTD_compressBound(raw.size()));
    const size_t n = ZSTD_compress(z.data(), z.size(), raw.data(), raw.size(), level);
    if (!ZSTD_isError(n) && n < best.bytes.size() && within_bomb_bound(raw.size(), n)) {
      z.resize(n);
      best = {1, std::move(z)};
    }
  }
  if (range_coding) {
    std::optional<std::vector<uint8_t>> m;
    try {
      m = model_encode(raw, section_shape(e, g, raw.data(), raw.size(), "section"));
    } catch (const CorruptError&) {
      m.reset();  // a header the shape cannot read: not this encoding
    }
    if (m && m->size() < best.bytes.size() && within_bomb_bound(raw.size(), m->size())) best = {2, std::move(*m)};
  }
  return best;
}

// The raw packed bytes of a section whose checksum has been verified.
std::vector<uint8_t> decode_section(const SectionEntry& e, const AngularGrid& g, const uint8_t* p, ByteReader& r) {
  if (e.encoding == 0) return {p, p + e.length};
  if (e.encoding == 2)
    return model_decode(p, size_t(e.length), section_shape(e, g, p, size_t(e.length), r.where()), e.raw_length, r.where());
  const unsigned long long size = ZSTD_getFrameContentSize(p, size_t(e.length));
  if (size != e.raw_length) r.fail("the zstd frame does not hold the " + std::to_string(e.raw_length) + " bytes the table says");
  std::vector<uint8_t> raw(size_t(e.raw_length));
  const size_t n = ZSTD_decompress(raw.data(), raw.size(), p, size_t(e.length));
  if (ZSTD_isError(n) || n != raw.size()) r.fail(std::string("zstd data is invalid (") + (ZSTD_isError(n) ? ZSTD_getErrorName(n) : "short") + ")");
  return raw;
}

bool same_section(const SectionEntry& a, const SectionEntry& b) {
  return a.kind == b.kind && a.version == b.version && a.codebook == b.codebook && a.material == b.material;
}

std::vector<uint8_t> read_database_file(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw InputError("cannot open database '" + path + "': not a regular file");
  const uintmax_t size = std::filesystem::file_size(path, ec);
  std::ifstream in(path, std::ios::binary);
  if (ec || !in) throw InputError("cannot open database '" + path + "': " + (ec ? ec.message() : std::strerror(errno)));
  std::vector<uint8_t> bytes(static_cast<size_t>(size));
  if (!in.read(reinterpret_cast<char*>(bytes.data()), std::streamsize(size)) || in.peek() != EOF)
    throw InputError("cannot read database '" + path + "' (it changed while being read?)");
  return bytes;
}

}  // namespace

bool has_content(const Database& db) {
  return !db.materials.empty() || db.codebooks.p1.rows() > 0 || db.codebooks.p4_index.rows() > 0;
}

PackSettings PackSettings::lossless() {
  PackSettings s;
  const ValueCoding raw{ValueCoding::Float32, 32};
  s.p1_values = s.c_values = s.p2_scale = s.p2_scale_hdr = s.p3_scale = s.p4_scale = s.p6_scale = raw;
  s.p4_scale_error = 0;
  return s;
}

void quantize_new_rows(Database& db, const PackSettings& settings) {
  const VersionMark codings = next_codings(db, settings);
  const VersionMark prev = last_mark(db);
  const VersionMark now = current_sizes(db);
  for (CodebookId id : kAllCodebooks)
    for (const Field& f : fields_of(db.codebooks, id))
      if (f.values) {
        const size_t r1 = f.values->rows(), r0 = std::min(prev.rows[id], r1);
        quantize_values(f.values->row(r0), (r1 - r0) * f.values->cols(), codings.*f.coding, section_name(id, 0),
                        f.error ? settings.*f.error : 0.0);
      }
  for (size_t i = std::min(prev.materials, now.materials); i < now.materials; ++i) {
    Material& m = db.materials[i];
    quantize_values(m.p6_scale.data(), m.p6_scale.size(), codings.p6_scale, "material '" + m.name + "' P6 scales");
  }
}

void publish_version(Database& db, const PackSettings& settings) {
  check_writable(db);
  if (!has_unpublished(db)) return;
  quantize_new_rows(db, settings);
  VersionMark mark = next_codings(db, settings);
  const VersionMark now = current_sizes(db);
  for (CodebookId id : kAllCodebooks) mark.rows[id] = now.rows[id];
  mark.materials = now.materials;
  db.versions.push_back(mark);
}

std::vector<uint8_t> serialize_database(const Database& input, const PackSettings& settings,
                                        const std::vector<uint8_t>* previous) {
  Database db = input;
  publish_version(db, settings);
  // Section payloads, in the order expected_sections() prescribes.
  std::vector<SectionEntry> entries;
  std::vector<std::vector<uint8_t>> payloads;
  VersionMark prev;
  for (size_t v = 0; v < db.versions.size(); ++v) {
    const VersionMark& mark = db.versions[v];
    const uint32_t version = uint32_t(v + 1);
    for (CodebookId id : kAllCodebooks)
      if (mark.rows[id] > prev.rows[id]) {
        SectionEntry e;
        e.kind = SectionKind::Codebook;
        e.version = version;
        e.codebook = id;
        payloads.push_back(encode_chunk(db.codebooks, id, version, prev, mark));
        entries.push_back(e);
      }
    for (size_t m = prev.materials; m < mark.materials; ++m) {
      SectionEntry e;
      e.kind = SectionKind::Material;
      e.version = version;
      e.material = db.materials[m].name;
      payloads.push_back(encode_material(db.materials[m], version, mark));
      entries.push_back(e);
    }
    prev = mark;
  }
  // Sections of an earlier file of this database whose decoded bytes are unchanged are kept verbatim.
  std::vector<Stored> stored(payloads.size());
  std::vector<bool> done(payloads.size(), false);
  if (previous) {
    try {
      const DatabaseHead old = parse_head(previous->data(), previous->size());
      const bool prefix = old.file_size == previous->size() && old.versions.size() <= db.versions.size() &&
                          std::equal(old.versions.begin(), old.versions.end(), db.versions.begin());
      for (size_t i = 0; prefix && i < old.sections.size() && i < entries.size(); ++i) {
        const SectionEntry& e = old.sections[i];
        const uint8_t* p = previous->data() + e.offset;
        ByteReader r(p, size_t(e.length), "previous");
        if (!same_section(e, entries[i]) || crc64(p, size_t(e.length)) != e.checksum) break;
        if (decode_section(e, db.codebooks.grid, p, r) != payloads[i]) continue;
        stored[i] = Stored{e.encoding, std::vector<uint8_t>(p, p + e.length)};
        done[i] = true;
      }
    } catch (const Error&) {
      // Not a usable earlier file: everything is encoded afresh.
    }
  }
  uint64_t head = kHeaderBytes + kVersionRecordBytes * db.versions.size() + 8;
  for (const auto& e : entries) head += kEntryFixedBytes + e.material.size();
  uint64_t offset = head;
  for (size_t i = 0; i < entries.size(); ++i) {
    const VersionMark& mark = db.versions[entries[i].version - 1];
    if (!done[i]) stored[i] = encode_section(payloads[i], entries[i], db.codebooks.grid, mark.zstd_level, mark.range_coding != 0);
    entries[i].offset = offset;
    entries[i].encoding = stored[i].encoding;
    entries[i].length = stored[i].bytes.size();
    entries[i].raw_length = payloads[i].size();
    entries[i].checksum = crc64(stored[i].bytes.data(), stored[i].bytes.size());
    offset += entries[i].length;
  }

  std::vector<uint8_t> out;
  ByteWriter w(out);
  w.bytes(kMagic, sizeof kMagic);
  w.u32(kFormatVersion);
  w.u32(uint32_t(db.versions.size()));
  const AngularGrid& g = db.codebooks.grid;
  for (int n : {g.n_beta, g.n_alpha, g.n_theta_v, g.n_phi_v}) w.u32(uint32_t(n));
  w.u32(uint32_t(entries.size()));
  w.u32(uint32_t(head));
  w.u64(offset);
  w.u64(0);  // reserved
  for (VersionMark& mark : db.versions) {
    for (CodebookId id : kAllCodebooks) w.u32(uint32_t(mark.rows[id]));
    w.u32(uint32_t(mark.materials));
    for (int k = 0; k < 6; ++k) {
      w.u8(codings(mark, k)->mode);
      w.u8(codings(mark, k)->bits);
    }
    w.u8(mark.zstd_level);
    w.u8(mark.range_coding);
    for (int k = 0; k < 2; ++k) w.u8(0);
  }
  for (const auto& e : entries) {
    w.u16(uint16_t(e.kind));
    w.u16(e.encoding);
    w.u32(e.version);
    w.u64(e.offset);
    w.u64(e.length);
    w.u64(e.raw_length);
    w.u64(e.checksum);
    w.u16(e.kind == SectionKind::Codebook ? uint16_t(e.codebook) : kNoCodebook);
    w.u16(uint16_t(e.material.size()));
    w.bytes(e.material.data(), e.material.size());
  }
  w.u64(crc64(out.data(), out.size()));
  for (const auto& p : stored) w.bytes(p.bytes.data(), p.bytes.size());
  return out;
}

uint64_t head_length(const uint8_t* data, size_t n) {
  ByteReader r(data, n, "database header");
  if (n < sizeof kMagic || std::memcmp(data, kMagic, sizeof kMagic) != 0)
    throw CorruptError("not a btfvq database (the file does not start with \"BTFVQDB1\")");
  if (n < kHeaderBytes) r.fail("truncated (" + std::to_string(n) + " of " + std::to_string(kHeaderBytes) + " bytes)");
  r.bytes(8);
  const uint32_t format = r.u32();
  if (format != kFormatVersion)
    r.fail("format version " + std::to_string(format) + " is not supported (this reader knows version 1)");
  r.bytes(24);
  return r.u32();
}

DatabaseHead parse_head(const uint8_t* data, size_t n, const std::string& where) {
  DatabaseHead h;
  try {
    h.head_length = head_length(data, n);
  } catch (const CorruptError& e) {
    throw CorruptError(where + ": " + e.what());
  }
  ByteReader r(data, n, where + ": header");
  const size_t min_head = kHeaderBytes + 8;
  if (h.head_length < min_head) r.fail("head length " + std::to_string(h.head_length) + " is too small");
  if (h.head_length > n)
    r.fail("truncated: the header and section table need " + std::to_string(h.head_length) + " bytes, only " +
           std::to_string(n) + " present");
  {
    ByteReader c(data + h.head_length - 8, 8, where);
    if (c.u64() != crc64(data, size_t(h.head_length) - 8))
      r.fail("checksum of the header and section table does not match (corrupted)");
  }
  r = ByteReader(data, size_t(h.head_length) - 8, where + ": header");
  r.bytes(8);
  h.format_version = r.u32();
  h.version = r.u32();
  int* grid[4] = {&h.grid.n_beta, &h.grid.n_alpha, &h.grid.n_theta_v, &h.grid.n_phi_v};
  for (int* g : grid) {
    const uint32_t v = r.u32();
    if (v > uint32_t(kMaxGridCount)) r.fail("grid count " + std::to_string(v) + " is out of range");
    *g = int(v);
  }
  try {
    h.grid.validate();
  } catch (const InputError& e) {
    r.fail(std::string("invalid grid: ") + e.what());
  }
  const uint32_t nsec = r.u32();
  r.u32();  // head length, read above
  h.file_size = r.u64();
  if (r.u64() != 0) r.fail("reserved field is not zero");
  if (h.file_size < h.head_length) r.fail("file size is smaller than the head");
  if (uint64_t(h.version) * kVersionRecordBytes + uint64_t(nsec) * kEntryFixedBytes > r.remaining())
    r.fail("version and section counts do not fit in the head");

  r = ByteReader(data, size_t(h.head_length) - 8, where + ": version records");
  r.bytes(kHeaderBytes);
  VersionMark prev;
  for (uint32_t v = 0; v < h.version; ++v) {
    VersionMark mark;
    for (CodebookId id : kAllCodebooks) mark.rows[id] = r.u32();
    mark.materials = r.u32();
    for (int k = 0; k < 6; ++k) {
      const uint8_t mode = r.u8(), bits = r.u8();
      const bool ok = mode == ValueCoding::Float32 ? bits == 32 : (mode <= ValueCoding::Log && (bits == 8 || bits == 16));
      if (!ok) r.fail("version " + std::to_string(v + 1) + " has an unknown value coding");
      *codings(mark, k) = ValueCoding{ValueCoding::Mode(mode), bits};
    }
    mark.zstd_level = r.u8();
    if (mark.zstd_level > ZSTD_maxCLevel()) r.fail("version " + std::to_string(v + 1) + " has an invalid zstd level");
    mark.range_coding = r.u8();
    if (mark.range_coding > 1) r.fail("version " + std::to_string(v + 1) + " has an unknown range coding flag");
    if (r.u16() != 0) r.fail("version " + std::to_string(v + 1) + ": reserved bytes are not zero");
    for (CodebookId id : kAllCodebooks)
      if (mark.rows[id] < prev.rows[id])
        r.fail("version " + std::to_string(v + 1) + " shrinks code-book " + codebook_name(id));
    if (mark.materials < prev.materials) r.fail("version " + std::to_string(v + 1) + " drops materials");
    h.versions.push_back(mark);
    prev = mark;
  }

  // Count before building the list, so that a corrupted material count cannot make us allocate.
  uint64_t implied = 0;
  prev = VersionMark();
  for (const VersionMark& mark : h.versions) {
    for (CodebookId id : kAllCodebooks) implied += mark.rows[id] > prev.rows[id] ? 1 : 0;
    implied += mark.materials - prev.materials;
    prev = mark;
  }
  if (implied != nsec)
    r.fail("the section table has " + std::to_string(nsec) + " sections, the versions imply " + std::to_string(implied));
  const auto expected = expected_sections(h.versions);
  r = ByteReader(data, size_t(h.head_length) - 8, where + ": section table");
  r.bytes(kHeaderBytes + kVersionRecordBytes * h.version);
  uint64_t offset = h.head_length;
  std::set<std::string> names;
  for (uint32_t i = 0; i < nsec; ++i) {
    SectionEntry e;
    const uint16_t kind = r.u16();
    e.encoding = r.u16();
    e.version = r.u32();
    e.offset = r.u64();
    e.length = r.u64();
    e.raw_length = r.u64();
    e.checksum = r.u64();
    const uint16_t id = r.u16();
    const uint16_t len = r.u16();
    e.material.assign(reinterpret_cast<const char*>(r.bytes(len)), len);
    e.kind = SectionKind(kind);
    const Expected& x = expected[i];
    const std::string s = "section " + std::to_string(i);
    if (kind != uint16_t(x.kind) || e.version != x.version)
      r.fail(s + ": kind " + std::to_string(kind) + " of version " + std::to_string(e.version) +
             " is not what the version records imply");
    if (x.kind == SectionKind::Codebook) {
      if (id != uint16_t(x.codebook) || len != 0) r.fail(s + ": expected the " + section_name(x.codebook, x.version));
      e.codebook = x.codebook;
    } else if (id != kNoCodebook || len == 0 || !names.insert(e.material).second) {
      r.fail(s + ": material entry without a name, with a code-book id, or a duplicate name");
    }
    if (e.encoding > 2) r.fail(s + ": encoding " + std::to_string(e.encoding) + " is not supported by this reader");
    if (e.encoding == 0 ? e.raw_length != e.length
                        : (!within_bomb_bound(e.raw_length, e.length) || e.raw_length > 0xFFFFFFFFu))
      r.fail(s + ": raw length " + std::to_string(e.raw_length) + " does not fit the stored length " +
             std::to_string(e.length));
    if (e.offset != offset || e.length > h.file_size - offset)
      r.fail(s + ": offset " + std::to_string(e.offset) + " / length " + std::to_string(e.length) +
             " does not continue the previous section inside the file");
    offset += e.length;
    h.sections.push_back(e);
  }
  if (r.remaining() != 0) r.fail("unexpected bytes after the section table");
  if (offset != h.file_size) r.fail("the sections do not end at the file size");
  return h;
}

std::vector<SectionEntry> sections_since(const DatabaseHead& head, uint32_t have) {
  std::vector<SectionEntry> out;
  for (const auto& s : head.sections)
    if (s.version > have) out.push_back(s);
  return out;
}

std::vector<uint8_t> decode_section_bytes(const SectionEntry& entry, const AngularGrid& grid,
                                          const std::vector<uint8_t>& stored) {
  ByteReader check(stored.data(), stored.size(), describe(entry, 0));
  if (stored.size() != entry.length) check.fail("has " + std::to_string(stored.size()) + " bytes, the table says " + std::to_string(entry.length));
  if (crc64(stored.data(), stored.size()) != entry.checksum) check.fail("checksum does not match (corrupted)");
  if (entry.encoding > 2 || (entry.encoding == 0 && entry.raw_length != entry.length) ||
      (entry.encoding != 0 && !within_bomb_bound(entry.raw_length, entry.length)))
    check.fail("unsupported encoding or raw length");
  return decode_section(entry, grid, stored.data(), check);
}

Database parse_database(const std::vector<uint8_t>& bytes, const std::string& where) {
  const DatabaseHead h = parse_head(bytes.data(), bytes.size(), where);
  if (h.file_size != bytes.size())
    throw CorruptError(where + ": the header says the file has " + std::to_string(h.file_size) + " bytes, it has " +
                       std::to_string(bytes.size()) + (bytes.size() < h.file_size ? " (truncated)" : ""));
  Database db;
  db.codebooks = Codebooks(h.grid);
  db.versions = h.versions;
  size_t next = 0;
  VersionMark prev;
  for (uint32_t v = 0; v < h.version; ++v) {
    const VersionMark& mark = h.versions[v];
    for (; next < h.sections.size() && h.sections[next].version == v + 1; ++next) {
      const SectionEntry& e = h.sections[next];
      const uint8_t* p = bytes.data() + e.offset;
      ByteReader check(p, size_t(e.length), where + ": " + describe(e, next));
      if (crc64(p, size_t(e.length)) != e.checksum) check.fail("checksum does not match (corrupted)");
      const std::vector<uint8_t> raw = decode_section(e, h.grid, p, check);
      ByteReader r(raw.data(), raw.size(), check.where());
      if (e.kind == SectionKind::Codebook) decode_chunk(r, db.codebooks, e.codebook, v + 1, prev, mark);
      else
        db.materials.push_back(decode_material(r, e.material, mark));
      if (r.remaining() != 0) r.fail(std::to_string(r.remaining()) + " unexpected bytes at the end");
    }
    prev = mark;
  }
  try {
    db.validate();
  } catch (const CorruptError& e) {
    throw CorruptError(where + ": " + e.what());
  }
  return db;
}

void write_database(const Database& db, const std::string& path, const PackSettings& settings) {
  std::vector<uint8_t> previous;
  if (is_database_file(path)) {
    try {
      previous = read_database_file(path);
    } catch (const Error&) {
      previous.clear();
    }
  }
  write_file_atomically(path, serialize_database(db, settings, previous.empty() ? nullptr : &previous));
}

double compression_ratio(uint64_t raw_bytes, uint64_t stored_bytes) {
  return stored_bytes > 0 ? double(raw_bytes) / double(stored_bytes) : 0.0;
}

uint64_t raw_bytes(const Database& db) {
  uint64_t raw = 0;
  for (const Material& m : db.materials) raw += m.raw_bytes;
  return raw;
}

Database read_database(const std::string& path) { return parse_database(read_database_file(path), path); }

DatabaseInfo inspect_database(const std::string& path) {
  const auto bytes = read_database_file(path);
  const Database db = parse_database(bytes, path);
  DatabaseInfo info;
  info.head = parse_head(bytes.data(), bytes.size(), path);
  size_t m = 0;
  for (const auto& s : info.head.sections) {
    if (s.kind == SectionKind::Codebook) {
      info.codebook_bytes[size_t(s.codebook)] += s.length;
      continue;
    }
    const Material& mat = db.materials[m++];
    info.materials.push_back({mat.name, mat.width, mat.height, mat.dynamic, mat.raw_bytes, s.version, s.length});
  }
  if (!db.versions.empty())
    info.codebook_rows = db.versions.back().rows;
  return info;
}

bool is_database_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  char magic[sizeof kMagic] = {};
  return in && in.read(magic, sizeof magic) && std::memcmp(magic, kMagic, sizeof kMagic) == 0;
}

}  // namespace btfvq
