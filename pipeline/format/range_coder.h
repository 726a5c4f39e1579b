#pragma once
// An adaptive binary range coder (the LZMA construction: 32-bit range, 11-bit probabilities that move
// 1/32 of the way towards each coded bit, carry propagated through a cached byte) and the few symbol
// models built from it. It codes the fields of a .btfdb section (docs/format.md, encoding 2); every
// probability is an integer, so the output is the same on every platform.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace btfvq {

// Probability that the next bit is 0, out of 2^15: the mean of a fast estimate (moves 1/8 of the way
// towards each bit) and a counting one (moves 1/2, 1/4, ... down to 1/128 of the way as bits are seen,
// i.e. close to the frequency so far), so that a model learns quickly and still settles on skewed
// statistics.
struct BitModel {
  uint16_t fast = 1 << 14;
  uint16_t slow = 1 << 14;
  uint8_t seen = 0;
  uint32_t p() const { return (uint32_t(fast) + slow) >> 1; }
  void update(unsigned bit);
};
inline constexpr BitModel kBitModelInit{};

class RangeEncoder {
 public:
  explicit RangeEncoder(std::vector<uint8_t>& out) : out_(out) {}
  void bit(BitModel& p, unsigned b);
  // Writes the final bytes; the encoder must not be used afterwards.
  void finish();

 private:
  void shift_low();
  std::vector<uint8_t>& out_;
  uint64_t low_ = 0;
  uint32_t range_ = 0xFFFFFFFFu;
  uint8_t cache_ = 0;
  uint64_t pending_ = 1;
};

// Decodes what RangeEncoder wrote. Reading past the input or a state no encoder can produce throws
// CorruptError naming `where`; finish() checks that exactly the input was consumed.
class RangeDecoder {
 public:
  RangeDecoder(const uint8_t* data, size_t size, std::string where);
  unsigned bit(BitModel& p);
  void finish() const;
  // Throws CorruptError("<where>: <what>").
  [[noreturn]] void fail(const std::string& what) const;

 private:
  uint8_t next();
  const uint8_t* p_;
  size_t n_;
  size_t pos_ = 0;
  uint32_t range_ = 0xFFFFFFFFu;
  uint32_t code_ = 0;
  std::string where_;
};

// An unsigned integer of up to 32 bits, binarized as its bit length (0..32, coded with a 6-level bit
// tree) and then the bits below the leading one: the top kContextBits of them with models that
// depend on the bit length and the bits before, the rest with one model per (bit length, position).
// Small values are cheap, and the models learn which magnitudes are common.
class IntegerModel {
 public:
  IntegerModel();
  void encode(RangeEncoder& e, uint32_t v);
  uint32_t decode(RangeDecoder& d);

 private:
  static constexpr int kContextBits = 3;
  BitModel length_[64];
  std::vector<BitModel> high_;  // 33 x 2^kContextBits
  std::vector<BitModel> low_;   // 33 x 32
};

// A symbol of `bits` bits (1..16) with a full bit tree: one adaptive model per prefix.
class SymbolModel {
 public:
  explicit SymbolModel(int bits);
  void encode(RangeEncoder& e, uint32_t v);
  uint32_t decode(RangeDecoder& d);
  int bits() const { return bits_; }

 private:
  int bits_;
  std::vector<BitModel> tree_;
};

}  // namespace btfvq
