#include "pipeline/format/range_coder.h"

#include <algorithm>
#include <bit>

#include <btfvq/error.h>

namespace btfvq {

namespace {

constexpr int kProbBits = 15;
constexpr int kFastBits = 3;
constexpr int kSlowBits = 7;
constexpr uint32_t kTop = 1u << 24;

}  // namespace

void BitModel::update(unsigned bit) {
  // Shift of the counting estimate: 1 + floor(log2(seen + 1)), at most kSlowBits.
  const int shift = std::min(kSlowBits, int(std::bit_width(unsigned(seen) + 1)));
  if (seen < 255) ++seen;
  const uint32_t one = 1u << kProbBits;
  if (bit == 0) {
    fast = uint16_t(fast + ((one - fast) >> kFastBits));
    slow = uint16_t(slow + ((one - slow) >> shift));
  } else {
    fast = uint16_t(fast - (fast >> kFastBits));
    slow = uint16_t(slow - (slow >> shift));
  }
  // Neither estimate may reach 0 or 2^15 (the range would collapse).
  slow = uint16_t(std::clamp<uint32_t>(slow, 32, one - 32));
}

void RangeEncoder::bit(BitModel& p, unsigned b) {
  const uint32_t bound = (range_ >> kProbBits) * p.p();
  if (b == 0) {
    range_ = bound;
  } else {
    low_ += bound;
    range_ -= bound;
  }
  p.update(b);
  while (range_ < kTop) {
    range_ <<= 8;
    shift_low();
  }
}

void RangeEncoder::shift_low() {
  // A byte can still change through a carry until a byte below 0xFF follows it: hold it (and any run
  // of 0xFF after it) until then.
  if (uint32_t(low_) < 0xFF000000u || (low_ >> 32) != 0) {
    const uint8_t carry = uint8_t(low_ >> 32);
    uint8_t held = cache_;
    do {
      out_.push_back(uint8_t(held + carry));
      held = 0xFF;
    } while (--pending_ != 0);
    cache_ = uint8_t(low_ >> 24);
  }
  ++pending_;
  low_ = (low_ & 0x00FFFFFFu) << 8;
}

void RangeEncoder::finish() {
  for (int i = 0; i < 5; ++i) shift_low();
}

RangeDecoder::RangeDecoder(const uint8_t* data, size_t size, std::string where)
    : p_(data), n_(size), where_(std::move(where)) {
  if (next() != 0) fail("range coder stream does not start with a zero byte");
  for (int i = 0; i < 4; ++i) code_ = (code_ << 8) | next();
  if (code_ == range_) fail("range coder stream starts with an impossible code");
}

uint8_t RangeDecoder::next() {
  if (pos_ >= n_) fail("range coder stream is truncated");
  return p_[pos_++];
}

void RangeDecoder::fail(const std::string& what) const { throw CorruptError(where_ + ": " + what); }

unsigned RangeDecoder::bit(BitModel& p) {
  const uint32_t bound = (range_ >> kProbBits) * p.p();
  unsigned b;
  if (code_ < bound) {
    range_ = bound;
    b = 0;
  } else {
    code_ -= bound;
    range_ -= bound;
    b = 1;
  }
  p.update(b);
  while (range_ < kTop) {
    range_ <<= 8;
    code_ = (code_ << 8) | next();
  }
  if (code_ >= range_) fail("range coder stream is inconsistent");
  return b;
}

void RangeDecoder::finish() const {
  if (pos_ != n_) fail("range coder stream has " + std::to_string(n_ - pos_) + " bytes past its end");
}

IntegerModel::IntegerModel() : high_(33u << kContextBits), low_(33 * 32) {}

void IntegerModel::encode(RangeEncoder& e, uint32_t v) {
  int n = 0;
  while (n < 32 && (v >> n) != 0) ++n;  // bit length, 0 for v = 0
  unsigned m = 1;
  for (int i = 5; i >= 0; --i) {
    const unsigned b = (unsigned(n) >> i) & 1;
    e.bit(length_[m], b);
    m = 2 * m + b;
  }
  unsigned ctx = 1;
  for (int i = n - 2; i >= 0; --i) {
    const unsigned b = (v >> i) & 1;
    const int from_top = n - 2 - i;
    if (from_top < kContextBits) {
      e.bit(high_[(size_t(n) << kContextBits) + ctx], b);
      ctx = 2 * ctx + b;
    } else {
      e.bit(low_[size_t(n) * 32 + size_t(i)], b);
    }
  }
}

uint32_t IntegerModel::decode(RangeDecoder& d) {
  unsigned m = 1;
  for (int i = 5; i >= 0; --i) m = 2 * m + d.bit(length_[m]);
  const int n = int(m - 64);
  if (n > 32) d.fail("an integer of more than 32 bits");
  if (n == 0) return 0;
  uint32_t v = 1;
  unsigned ctx = 1;
  for (int i = n - 2; i >= 0; --i) {
    const int from_top = n - 2 - i;
    unsigned b;
    if (from_top < kContextBits) {
      b = d.bit(high_[(size_t(n) << kContextBits) + ctx]);
      ctx = 2 * ctx + b;
    } else {
      b = d.bit(low_[size_t(n) * 32 + size_t(i)]);
    }
    v = (v << 1) | b;
  }
  return v;
}

SymbolModel::SymbolModel(int bits) : bits_(bits), tree_(size_t(1) << bits) {}

void SymbolModel::encode(RangeEncoder& e, uint32_t v) {
  unsigned m = 1;
  for (int i = bits_ - 1; i >= 0; --i) {
    const unsigned b = (v >> i) & 1;
    e.bit(tree_[m], b);
    m = 2 * m + b;
  }
}

uint32_t SymbolModel::decode(RangeDecoder& d) {
  unsigned m = 1;
  for (int i = 0; i < bits_; ++i) m = 2 * m + d.bit(tree_[m]);
  return m - (1u << bits_);
}

}  // namespace btfvq
