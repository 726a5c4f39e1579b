#pragma once
// The .btfdb database file (DESIGN.md steps 7-8; byte-level spec in docs/format.md): a header, the
// list of published versions, a section table (kind, version, offset, length, CRC-64 per section,
// guarded itself by a CRC-64) and then one section per (code-book, version) chunk and one per
// material. Versions are append-only: writing version N+1 reproduces every section of version N byte
// for byte, so a client holding N fetches only the sections added since (HTTP Range on the table).
//
// Floats are scalar-quantized per chunk with that chunk's own min/max (paper Sec. 4.5), indices are
// packed in ceil(log2(size of the target code-book at that version)) bits.
#include <cstdint>
#include <string>
#include <vector>

#include "pipeline/codebook.h"

namespace btfvq {

// How a new version's float values are stored. Defaults (errors measured in tests/test_database.cpp,
// documented in docs/format.md): scales 8-bit logarithmic (HDR P2 16-bit), P1 8-bit logarithmic,
// chroma C 16-bit linear.
struct PackSettings {
  ValueCoding p1_values{ValueCoding::Log, 8};
  ValueCoding c_values{ValueCoding::Linear, 16};
  ValueCoding p2_scale{ValueCoding::Log, 8};
  ValueCoding p2_scale_hdr{ValueCoding::Log, 16};  // used when any material of the database is HDR
  ValueCoding p3_scale{ValueCoding::Log, 8};
  ValueCoding p4_scale{ValueCoding::Log, 8};
  ValueCoding p6_scale{ValueCoding::Log, 8};
  // P4 scales (each phi_v group's brightness within a normalized P4 entry, chunks spanning a ratio of
  // about 1.4-1.7) use only as many of their 8-bit codes as keep them within this relative error
  // (quantize_values): the codes resolve 0.06 %, which the entropy coder cannot remove. Measured at
  // 0.25 %: wool and leather 128 databases 3.3 % and 2.2 % smaller for MSSIM -0.0002 or less, but
  // proposte 256 only 0.15 % smaller for MSSIM -0.0002: its P4 rows are few and each serves many
  // texels of a smooth image (docs/format.md "Scalar quantization").
  double p4_scale_error = 0.0025;
  // Entropy coding beyond the paper: each section of the new version is stored as the smallest of
  // raw packed (encoding 0), zstd at this level (encoding 1; 0 = not tried) and, with range_coding,
  // the modelled range coder (encoding 2, pipeline/format/section_coding.h). zstd_level 0 and range_coding
  // false store every section raw packed.
  int zstd_level = 19;
  bool range_coding = true;

  // 32-bit floats everywhere: an imported original (BTFBASE) database is stored without loss.
  static PackSettings lossless();
};

enum class SectionKind : uint16_t { Codebook = 1, Material = 2 };

// One row of the section table.
struct SectionEntry {
  SectionKind kind = SectionKind::Codebook;
  uint16_t encoding = 0;  // 0 = raw packed, 1 = zstd frame of the raw packed bytes, 2 = modelled range coder
  uint32_t version = 0;   // the database version that added this section
  CodebookId codebook = CodebookId::P1;  // kind Codebook
  std::string material;                  // kind Material
  uint64_t offset = 0;  // from the start of the file
  uint64_t length = 0;  // stored bytes
  uint64_t raw_length = 0;  // bytes after decoding (= length for encoding 0)
  uint64_t checksum = 0;    // CRC-64/XZ of the stored bytes

  bool operator==(const SectionEntry& o) const = default;
};

// Header, versions and section table: everything before the first section.
struct DatabaseHead {
  uint32_t format_version = 0;
  uint32_t version = 0;  // latest published version (= versions.size())
  AngularGrid grid;
  uint64_t head_length = 0;  // bytes from the start of the file to the first section
  uint64_t file_size = 0;
  std::vector<VersionMark> versions;  // ValueCodings as requested when each version was written
  std::vector<SectionEntry> sections;
};

// Fixed part of the header: fetch these bytes first, then head_length() bytes for the whole head.
inline constexpr size_t kHeaderBytes = 56;
// head_length from the first kHeaderBytes bytes (CorruptError if they are not a .btfdb header).
uint64_t head_length(const uint8_t* data, size_t n);
// Parses and checks the head (magic, format version, head CRC-64, table consistency) from the first
// n >= head_length bytes of a file. `where` names the file in error messages.
DatabaseHead parse_head(const uint8_t* data, size_t n, const std::string& where = "database");
// The sections a client that holds version `have` must fetch to reach head.version (delta download).
std::vector<SectionEntry> sections_since(const DatabaseHead& head, uint32_t have);

struct MaterialInfo {
  std::string name;
  int width = 0;
  int height = 0;
  Dynamic dynamic = Dynamic::LDR;
  uint64_t raw_bytes = 0;
  uint32_t version = 0;       // version that added it
  uint64_t section_bytes = 0;  // its bytes in the file
};

struct DatabaseInfo {
  DatabaseHead head;
  std::vector<MaterialInfo> materials;
  CodebookSizes codebook_rows;  // at the latest version
  uint64_t codebook_bytes[kCodebookCount] = {};  // their bytes in the file (all versions)
};

// Whether the database holds a material or a code-book row: an empty one takes the angular grid of
// its first compression, one with content keeps its own.
bool has_content(const Database& db);

// Rounds every float not yet published (rows past the last VersionMark, materials past its count)
// to exactly the value the next written file will store, so that the in-memory model and the
// re-read file decode bit-identically. Idempotent.
void quantize_new_rows(Database& db, const PackSettings& settings = {});
// quantize_new_rows() and then a new VersionMark for everything appended since the last one (also
// when nothing was appended but no version exists yet). This is what write_database() publishes.
void publish_version(Database& db, const PackSettings& settings = {});

// The file bytes of `db` with its unpublished content published as a new version (the previously
// published versions are reproduced byte for byte). A pure function of (db, settings) for a given
// libzstd; given the bytes of an earlier file of the same database (`previous`), a section whose
// decoded bytes are unchanged is copied from it verbatim, so old sections stay byte-identical even
// if a newer libzstd would compress them differently. An unusable `previous` is ignored.
std::vector<uint8_t> serialize_database(const Database& db, const PackSettings& settings = {},
                                        const std::vector<uint8_t>* previous = nullptr);
// One section on its own (random access: its stored bytes fetched by range using the head): checks
// the checksum and decodes encoding 0, 1 or 2 to the raw packed bytes (docs/format.md). Throws
// CorruptError naming the section on any problem.
std::vector<uint8_t> decode_section_bytes(const SectionEntry& entry, const AngularGrid& grid,
                                          const std::vector<uint8_t>& stored);
// Checks everything (see read_database) and returns the database with its versions.
Database parse_database(const std::vector<uint8_t>& bytes, const std::string& where = "database");

// serialize_database() written atomically (temporary file, fsync, rename), reusing the sections of
// an existing database at `path` (see `previous` above). Invalid input (InputError/CorruptError from
// Database::validate) changes nothing on disk.
void write_database(const Database& db, const std::string& path, const PackSettings& settings = {});
// Reads and validates everything: magic, format version, head checksum, every section's checksum,
// lengths, offsets, the section order implied by the versions, index ranges. Any problem throws
// CorruptError naming the file and section; a missing or unreadable file throws InputError.
Database read_database(const std::string& path);
// The compression ratio raw : stored — the measured input's bytes as MeasuredSample::raw_bytes()
// counts them (summed over materials) over the bytes of the database file; 0 for no bytes. The one
// definition of the ratio: reports, `btfvq info`/`eval`, the catalogue and the benches use it.
double compression_ratio(uint64_t raw_bytes, uint64_t stored_bytes);
uint64_t raw_bytes(const Database& db);

// Versions, sections, code-book sizes and materials of a file (fully validated like read_database).
DatabaseInfo inspect_database(const std::string& path);
// True if the file exists and starts with the .btfdb magic.
bool is_database_file(const std::string& path);

}  // namespace btfvq
