#pragma once
// The byte-level building blocks of the .btfdb format (docs/format.md): little-endian fields,
// compact indices packed in ceil(log2(S)) bits (paper Sec. 4.5), scalar quantization of floats with
// per-chunk min/max, and the CRC-64 that guards every section.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "pipeline/codebook.h"

namespace btfvq {

// CRC-64/XZ (ECMA-182 polynomial, reflected, init and final xor all ones): "123456789" -> 0x995dc9bbdf1939fa.
uint64_t crc64(const uint8_t* data, size_t n);

// Bits of an index into a code-book of `target_size` entries: ceil(log2(target_size)), at least 1.
int index_bits(uint64_t target_size);

// Appends little-endian fields to a byte vector.
class ByteWriter {
 public:
  explicit ByteWriter(std::vector<uint8_t>& out) : out_(out) {}
  void u8(uint8_t v) { out_.push_back(v); }
  void u16(uint16_t v) { put(v, 2); }
  void u32(uint32_t v) { put(v, 4); }
  void u64(uint64_t v) { put(v, 8); }
  void f32(float v);
  void bytes(const void* p, size_t n);
  size_t size() const { return out_.size(); }

 private:
  void put(uint64_t v, int n);
  std::vector<uint8_t>& out_;
};

// Reads little-endian fields from a bounded byte range; any read past the end throws CorruptError
// naming `where` (e.g. "section 3 (code-book P2, version 1)").
class ByteReader {
 public:
  ByteReader(const uint8_t* data, size_t size, std::string where) : p_(data), n_(size), where_(std::move(where)) {}
  uint8_t u8();
  uint16_t u16() { return uint16_t(get(2)); }
  uint32_t u32() { return uint32_t(get(4)); }
  uint64_t u64() { return get(8); }
  float f32();
  const uint8_t* bytes(size_t n);
  size_t remaining() const { return n_ - pos_; }
  size_t position() const { return pos_; }
  const std::string& where() const { return where_; }
  // Throws CorruptError("<where>: <what>").
  [[noreturn]] void fail(const std::string& what) const;

 private:
  uint64_t get(int n);
  const uint8_t* p_;
  size_t n_;
  size_t pos_ = 0;
  std::string where_;
};

// Index field: u8 width, then the n values packed LSB-first in `width` bits each.
void write_indices(ByteWriter& w, const uint32_t* values, size_t n, int width);
// Reads an index field of n values; throws CorruptError unless the stored width equals `width`,
// every value is below `limit` and the padding bits of the last byte are zero.
std::vector<uint32_t> read_indices(ByteReader& r, size_t n, int width, uint64_t limit, const std::string& what);

// The scalar quantizer of one value field (paper Sec. 4.5), fitted to the values of one chunk.
//   Linear: v = min + (max - min) q / L,                      L = 2^bits - 1
//   Log:    q = 0 -> 0; else v = exp(ln min + (ln max - ln min)(q - 1)/(L - 1))
// Both evaluated in double and rounded to float; q = L gives exactly max (and Log q = 1 exactly min).
struct Quantizer {
  ValueCoding coding;  // the mode actually used (Log falls back to Linear when it cannot apply)
  float min = 0;
  float max = 0;

  // Fits to the values (which must be finite: InputError naming `what` otherwise).
  static Quantizer fit(const float* v, size_t n, ValueCoding requested, const std::string& what);
  uint32_t levels() const { return coding.bits >= 32 ? 0 : uint32_t((uint64_t(1) << coding.bits) - 1); }
  float value(uint32_t code) const;
  // The code whose value is nearest to v (ties to the lower value), and among codes with that same
  // value the smallest: so quantizing already quantized values reproduces the same codes.
  uint32_t code(float v) const;
  // How many evenly spread Log codes (1 and levels() among them) keep every positive value within
  // `relative_error` of itself (ln(max/min) / (2 (used - 1)) <= relative_error); 0 when that takes
  // every code, for Linear, and for relative_error 0.
  uint32_t levels_for(double relative_error) const;
  // The code nearest to v among `used` such codes (ties to the lower value); 0 for v <= 0.
  uint32_t coarse_code(float v, uint32_t used) const;
};

// Value field: u8 mode, u8 bits, f32 min, f32 max, then n codes packed LSB-first in `bits` bits
// (Float32: n raw little-endian IEEE floats).
void write_values(ByteWriter& w, const float* v, size_t n, ValueCoding requested, const std::string& what);
std::vector<float> read_values(ByteReader& r, size_t n, const std::string& what);
// Replaces the values by what write_values() + read_values() would give back. With relative_error
// > 0 (Log only), the values snap to the fewer codes of Quantizer::levels_for(relative_error): still
// codes of `requested`, so a reader sees an ordinary field, but the entropy coder sees fewer values.
void quantize_values(float* v, size_t n, ValueCoding requested, const std::string& what, double relative_error = 0);

}  // namespace btfvq
