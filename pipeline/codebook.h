#pragma once
// The MLVQ code-book hierarchy of paper Fig. 3 and eq. 4, in memory, unquantized.
//
//   luminance:  P1 (n_beta densities) <- P2 (n_alpha x (P1 index, scale))
//   chroma:     C (a, b pairs) <- I1 (n_beta C indices) <- I2 (n_alpha I1 indices)
//   merged:     M (P2 index, I2 index) <- P3 (n_theta_v x (M index, scale)) <- P4 (n_phi_v x (P3 index, scale))
//   material:   P6 (W x H x (P4 index, scale)), one per material
//
// All indices are 0-based. Every code-book but P6 is shared by all materials of a database and only
// ever grows (append-only): an entry keeps its index forever, which is what lets existing material
// sections and old database versions stay byte-identical.
#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "pipeline/btf.h"
#include "pipeline/parametrization.h"

namespace btfvq {

// A row-major table with a fixed number of columns; rows are appended.
template <class T>
class Table {
 public:
  Table() = default;
  explicit Table(size_t cols) : cols_(cols) {}
  size_t cols() const { return cols_; }
  size_t rows() const { return cols_ ? data_.size() / cols_ : 0; }
  const T* row(size_t r) const { return data_.data() + r * cols_; }
  T* row(size_t r) { return data_.data() + r * cols_; }
  const T& at(size_t r, size_t c) const { return data_[r * cols_ + c]; }
  T& at(size_t r, size_t c) { return data_[r * cols_ + c]; }
  // Appends one row (cols() values) and returns its index.
  uint32_t append(const T* values) {
    data_.insert(data_.end(), values, values + cols_);
    return uint32_t(rows() - 1);
  }
  void resize_rows(size_t rows) { data_.resize(rows * cols_); }
  std::vector<T>& data() { return data_; }
  const std::vector<T>& data() const { return data_; }
  bool operator==(const Table& o) const { return cols_ == o.cols_ && data_ == o.data_; }

 private:
  size_t cols_ = 0;
  std::vector<T> data_;
};

// The shared code-books, in the order their chunks appear within a database version (docs/format.md);
// the value is the code-book's id in the file.
enum class CodebookId : uint16_t { P1 = 0, C = 1, I1 = 2, I2 = 3, P2 = 4, M = 5, P3 = 6, P4 = 7 };
inline constexpr int kCodebookCount = 8;
inline constexpr CodebookId kAllCodebooks[kCodebookCount] = {CodebookId::P1, CodebookId::C,  CodebookId::I1,
                                                             CodebookId::I2, CodebookId::P2, CodebookId::M,
                                                             CodebookId::P3, CodebookId::P4};
// "P1", "C", ... "P4" (the one name table: reports, JSON keys, file listings).
const char* codebook_name(CodebookId id);

struct Codebooks;

// Rows per code-book, indexed by CodebookId: sizes in progress reports, versions and file listings.
struct CodebookSizes {
  std::array<size_t, kCodebookCount> rows{};

  size_t& operator[](CodebookId id) { return rows[size_t(id)]; }
  size_t operator[](CodebookId id) const { return rows[size_t(id)]; }
  bool operator==(const CodebookSizes& o) const = default;
  static CodebookSizes of(const Codebooks& k);
};
// As a JSON object {"P1": rows, ..., "P4": rows}; from_json reads what to_json wrote (missing names are 0).
void to_json(nlohmann::json& j, const CodebookSizes& z);
void from_json(const nlohmann::json& j, CodebookSizes& z);

// The shared code-books of one database.
struct Codebooks {
  AngularGrid grid;
  Table<float> p1;           // rows x n_beta: luminance densities along beta (each row sums to 1)
  Table<float> c;            // rows x 2: chroma (a, b) in coding-space units
  Table<uint32_t> i1;        // rows x n_beta: indices into C
  Table<uint32_t> i2;        // rows x n_alpha: indices into I1
  Table<uint32_t> p2_index;  // rows x n_alpha: indices into P1
  Table<float> p2_scale;     // rows x n_alpha: scale x P1 row = luminance
  Table<uint32_t> m;         // rows x 2: (P2 index, I2 index)
  Table<uint32_t> p3_index;  // rows x n_theta_v: indices into M
  Table<float> p3_scale;
  Table<uint32_t> p4_index;  // rows x n_phi_v: indices into P3
  Table<float> p4_scale;

  Codebooks() = default;
  explicit Codebooks(const AngularGrid& g);

  bool operator==(const Codebooks& o) const = default;
};

// One material: its spatial index P6 and what is needed to turn decoded values back into RGB.
struct Material {
  std::string name;
  int width = 0;
  int height = 0;
  Dynamic dynamic = Dynamic::LDR;  // LDR: YCbCr coding space; HDR: LogLuv coding space
  uint64_t raw_bytes = 0;           // size of the measured input, for the compression ratio
  std::vector<int32_t> p6_index;    // height x width, row-major [y][x]; -1 = texel not compressed
  std::vector<float> p6_scale;      // height x width

  bool operator==(const Material& o) const = default;
};

// How the float values one database version appended to a code-book were quantized (paper Sec. 4.5;
// docs/format.md): raw IEEE floats, or `bits`-bit codes uniform in the value (Linear) or in its
// logarithm (Log, bounded relative error; falls back to Linear for a chunk with negative values).
struct ValueCoding {
  enum Mode : uint8_t { Float32 = 0, Linear = 1, Log = 2 };
  Mode mode = Float32;
  uint8_t bits = 32;  // 32 with Float32; 8 or 16 otherwise

  bool operator==(const ValueCoding& o) const = default;
};

// One published database version: code-book sizes and material count after it, and how its new
// values were quantized, so that rewriting the database reproduces that version's sections byte for
// byte (append-only versions, delta downloads).
struct VersionMark {
  CodebookSizes rows;
  size_t materials = 0;
  ValueCoding p1_values, c_values, p2_scale, p3_scale, p4_scale, p6_scale;
  uint8_t zstd_level = 0;  // 0: sections stored raw packed; else zstd at this level where it is smaller
  uint8_t range_coding = 0;  // 1: the modelled range coder (section encoding 2) too, smallest wins

  bool operator==(const VersionMark& o) const = default;
};

// A whole database in memory: shared code-books and the materials that index into them.
struct Database {
  Codebooks codebooks;
  std::vector<Material> materials;
  // Published versions, oldest first (version number = position + 1). Rows and materials past the
  // last mark are not yet published; write_database() publishes them as the next version.
  std::vector<VersionMark> versions;

  bool operator==(const Database& o) const = default;

  const Material* find(const std::string& name) const;
  // Throws CorruptError naming the code-book, row and column of the first index that points past
  // the end of its target code-book (or a P6 index past P4).
  void validate() const;
};

// Rows of one code-book per id: how many reclaim_unreachable() removed and kept.
struct ReclaimReport {
  CodebookSizes removed, reachable;
};

// Removes the rows not yet published (past the last VersionMark) that no material's P6 reaches
// through the code-book chain -- the children of compositions the encoder tried and rejected, entries
// that later ones made redundant -- and renumbers the rest, rewriting the indices of unpublished rows
// and of every material: the lower code-books' rows keep their order, P4's follow the order in which
// the materials' P6 first reach them. Published rows are never touched (append-only: old
// versions stay byte-identical). `reachable` counts every reachable row, published or not.
ReclaimReport reclaim_unreachable(Database& db);

}  // namespace btfvq
