#include "pipeline/format/packing.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>

#include <btfvq/error.h>

namespace btfvq {

namespace {

std::array<uint64_t, 256> make_crc64_table() {
  constexpr uint64_t poly = 0xC96C5795D7870F42ull;  // ECMA-182, reflected
  std::array<uint64_t, 256> t{};
  for (uint64_t i = 0; i < 256; ++i) {
    uint64_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1) ? (c >> 1) ^ poly : c >> 1;
    t[i] = c;
  }
  return t;
}

// Packs `width`-bit values LSB-first: bit k of the stream is bit (k mod 8) of byte k / 8.
void pack(ByteWriter& w, const uint32_t* v, size_t n, int width) {
  uint64_t acc = 0;
  int held = 0;
  std::vector<uint8_t> out;
  out.reserve((n * size_t(width) + 7) / 8);
  for (size_t i = 0; i < n; ++i) {
    acc |= uint64_t(v[i]) << held;
    held += width;
    while (held >= 8) {
      out.push_back(uint8_t(acc));
      acc >>= 8;
      held -= 8;
    }
  }
  if (held > 0) out.push_back(uint8_t(acc));
  w.bytes(out.data(), out.size());
}

// The inverse of pack(); the padding bits after the last value must be zero.
std::vector<uint32_t> unpack(ByteReader& r, size_t n, int width, const std::string& what) {
  if (n > r.remaining() * 8 / size_t(width))
    r.fail(what + ": " + std::to_string(n) + " values of " + std::to_string(width) + " bits do not fit in the " +
           std::to_string(r.remaining()) + " bytes left");
  const size_t nbytes = (n * size_t(width) + 7) / 8;
  const uint8_t* p = r.bytes(nbytes);
  std::vector<uint32_t> v(n);
  const uint64_t mask = (uint64_t(1) << width) - 1;
  uint64_t acc = 0;
  int held = 0;
  size_t b = 0;
  for (size_t i = 0; i < n; ++i) {
    while (held < width) {
      acc |= uint64_t(p[b++]) << held;
      held += 8;
    }
    v[i] = uint32_t(acc & mask);
    acc >>= width;
    held -= width;
  }
  if (acc != 0) r.fail(what + ": padding bits after the last value are not zero");
  return v;
}

bool valid_coding(uint8_t mode, uint8_t bits) {
  if (mode == ValueCoding::Float32) return bits == 32;
  return (mode == ValueCoding::Linear || mode == ValueCoding::Log) && (bits == 8 || bits == 16);
}

float positive_zero(float v) { return v == 0.0f ? 0.0f : v; }

}  // namespace

uint64_t crc64(const uint8_t* data, size_t n) {
  static const std::array<uint64_t, 256> table = make_crc64_table();
  uint64_t c = ~uint64_t(0);
  for (size_t i = 0; i < n; ++i) c = table[(c ^ data[i]) & 0xFF] ^ (c >> 8);
  return ~c;
}

int index_bits(uint64_t target_size) {
  return target_size <= 2 ? 1 : int(std::bit_width(target_size - 1));
}

void ByteWriter::put(uint64_t v, int n) {
  for (int i = 0; i < n; ++i) out_.push_back(uint8_t(v >> (8 * i)));
}

void ByteWriter::f32(float v) { u32(std::bit_cast<uint32_t>(v)); }

void ByteWriter::bytes(const void* p, size_t n) {
  const auto* b = static_cast<const uint8_t*>(p);
  out_.insert(out_.end(), b, b + n);
}

void ByteReader::fail(const std::string& what) const { throw CorruptError(where_ + ": " + what); }

uint64_t ByteReader::get(int n) {
  if (remaining() < size_t(n)) fail("truncated (needs " + std::to_string(n) + " more bytes at offset " + std::to_string(pos_) + ")");
  uint64_t v = 0;
  for (int i = 0; i < n; ++i) v |= uint64_t(p_[pos_ + size_t(i)]) << (8 * i);
  pos_ += size_t(n);
  return v;
}

uint8_t ByteReader::u8() { return uint8_t(get(1)); }

float ByteReader::f32() { return std::bit_cast<float>(u32()); }

const uint8_t* ByteReader::bytes(size_t n) {
  if (remaining() < n) fail("truncated (needs " + std::to_string(n) + " bytes at offset " + std::to_string(pos_) + ")");
  const uint8_t* p = p_ + pos_;
  pos_ += n;
  return p;
}

void write_indices(ByteWriter& w, const uint32_t* values, size_t n, int width) {
  w.u8(uint8_t(width));
  pack(w, values, n, width);
}

std::vector<uint32_t> read_indices(ByteReader& r, size_t n, int width, uint64_t limit, const std::string& what) {
  const int stored = r.u8();
  if (stored != width)
    r.fail(what + ": index width " + std::to_string(stored) + " bits, expected " + std::to_string(width));
  auto v = unpack(r, n, width, what);
  for (size_t i = 0; i < n; ++i)
    if (v[i] >= limit)
      r.fail(what + ": value " + std::to_string(i) + " is " + std::to_string(v[i]) + ", past the end (" +
             std::to_string(limit) + " entries)");
  return v;
}

Quantizer Quantizer::fit(const float* v, size_t n, ValueCoding requested, const std::string& what) {
  Quantizer q;
  q.coding = requested;
  bool all_non_negative = true;
  float lo = INFINITY, hi = -INFINITY, lo_positive = INFINITY;
  for (size_t i = 0; i < n; ++i) {
    if (!std::isfinite(v[i]))
      throw InputError(what + ": value " + std::to_string(i) + " is not a finite number");
    lo = std::min(lo, v[i]);
    hi = std::max(hi, v[i]);
    if (v[i] < 0) all_non_negative = false;
    if (v[i] > 0) lo_positive = std::min(lo_positive, v[i]);
  }
  if (n == 0) lo = hi = 0;
  if (q.coding.mode == ValueCoding::Log && !(all_non_negative && hi > 0)) q.coding.mode = ValueCoding::Linear;
  q.min = positive_zero(q.coding.mode == ValueCoding::Log ? lo_positive : lo);
  q.max = positive_zero(hi);
  return q;
}

float Quantizer::value(uint32_t code) const {
  const uint32_t L = levels();
  if (coding.mode == ValueCoding::Log) {
    if (code == 0) return 0.0f;
    if (code == 1) return min;
    if (code >= L) return max;
    const double t = double(code - 1) / double(L - 1);
    const double lmin = std::log(double(min)), lmax = std::log(double(max));
    return std::clamp(float(std::exp(lmin + (lmax - lmin) * t)), min, max);
  }
  if (code >= L) return max;
  const double t = double(code) / double(L);
  return std::clamp(float(double(min) + (double(max) - double(min)) * t), min, max);
}

uint32_t Quantizer::code(float v) const {
  const uint32_t first = coding.mode == ValueCoding::Log ? 1 : 0, L = levels();
  if (coding.mode == ValueCoding::Log && v <= 0) return 0;
  // Smallest code in [first, L] whose value is >= target. value() is non-decreasing in the code, so
  // walking from the analytic guess gives the same answer as a binary search, in a step or two.
  auto lower_bound = [&](float target, double guess) {
    uint32_t q = uint32_t(std::clamp(guess, double(first), double(L)));
    while (q > first && value(q - 1) >= target) --q;
    while (q < L && value(q) < target) ++q;
    return q;
  };
  double guess = 0;
  if (max > min) {
    guess = coding.mode == ValueCoding::Log
                ? 1 + (std::log(double(v)) - std::log(double(min))) / (std::log(double(max)) - std::log(double(min))) * (L - 1)
                : (double(v) - min) / (double(max) - min) * L;
    if (!std::isfinite(guess)) guess = first;
  }
  const uint32_t above = lower_bound(v, std::ceil(guess));
  if (above == first || value(above) - v < v - value(above - 1)) return above;
  return lower_bound(value(above - 1), double(above - 1));
}

void write_values(ByteWriter& w, const float* v, size_t n, ValueCoding requested, const std::string& what) {
  const Quantizer q = Quantizer::fit(v, n, requested, what);
  w.u8(q.coding.mode);
  w.u8(q.coding.bits);
  w.f32(q.min);
  w.f32(q.max);
  if (q.coding.mode == ValueCoding::Float32) {
    for (size_t i = 0; i < n; ++i) w.f32(v[i]);
    return;
  }
  std::vector<uint32_t> codes(n);
  for (size_t i = 0; i < n; ++i) codes[i] = q.code(v[i]);
  pack(w, codes.data(), n, q.coding.bits);
}

std::vector<float> read_values(ByteReader& r, size_t n, const std::string& what) {
  Quantizer q;
  const uint8_t mode = r.u8(), bits = r.u8();
  if (!valid_coding(mode, bits))
    r.fail(what + ": unknown value coding (mode " + std::to_string(mode) + ", " + std::to_string(bits) + " bits)");
  q.coding = ValueCoding{ValueCoding::Mode(mode), bits};
  q.min = r.f32();
  q.max = r.f32();
  if (!std::isfinite(q.min) || !std::isfinite(q.max) || q.min > q.max ||
      (q.coding.mode == ValueCoding::Log && !(q.min > 0)))
    r.fail(what + ": invalid quantizer range [" + std::to_string(q.min) + ", " + std::to_string(q.max) + "]");
  std::vector<float> out(0);
  if (q.coding.mode == ValueCoding::Float32) {
    if (n > r.remaining() / 4)
      r.fail(what + ": " + std::to_string(n) + " floats do not fit in the " + std::to_string(r.remaining()) + " bytes left");
    out.resize(n);
    for (size_t i = 0; i < n; ++i) {
      out[i] = r.f32();
      if (!std::isfinite(out[i])) r.fail(what + ": value " + std::to_string(i) + " is not a finite number");
    }
    return out;
  }
  const auto codes = unpack(r, n, q.coding.bits, what);
  out.resize(n);
  for (size_t i = 0; i < n; ++i) out[i] = q.value(codes[i]);
  return out;
}

uint32_t Quantizer::levels_for(double relative_error) const {
  if (coding.mode != ValueCoding::Log || !(relative_error > 0) || !(max > min)) return 0;
  // The used codes are whole codes, so neighbours lie up to ceil(span / (used - 1)) codes apart.
  const double span = double(levels() - 1), step = std::log(double(max) / double(min)) / span;
  for (double used = std::max(2.0, std::ceil(span * step / (2 * relative_error)) + 1); used < double(levels()); ++used)
    if (std::ceil(span / (used - 1)) * step / 2 <= relative_error) return uint32_t(used);
  return 0;
}

uint32_t Quantizer::coarse_code(float v, uint32_t used) const {
  if (v <= 0) return 0;
  const double span = double(levels() - 1), per = span / double(used - 1);
  auto code_of = [&](int64_t j) { return 1 + uint32_t(std::llround(double(j) * per)); };
  const int64_t near = std::llround(double(code(v) - 1) / per);
  uint32_t best = 0;
  for (int64_t j = std::max<int64_t>(0, near - 1); j <= std::min<int64_t>(int64_t(used) - 1, near + 1); ++j)
    if (const uint32_t c = code_of(j); best == 0 || std::abs(value(c) - v) < std::abs(value(best) - v)) best = c;
  return best;
}

void quantize_values(float* v, size_t n, ValueCoding requested, const std::string& what, double relative_error) {
  const Quantizer q = Quantizer::fit(v, n, requested, what);
  if (q.coding.mode == ValueCoding::Float32) return;
  const uint32_t used = q.levels_for(relative_error);
  for (size_t i = 0; i < n; ++i) v[i] = q.value(used ? q.coarse_code(v[i], used) : q.code(v[i]));
}

}  // namespace btfvq
