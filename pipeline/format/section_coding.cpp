#include "pipeline/format/section_coding.h"

#include <algorithm>
#include <cstring>
#include <type_traits>

#include <btfvq/error.h>
#include "pipeline/format/range_coder.h"

namespace btfvq {

namespace {

// Per field, u8 model (docs/format.md, encoding 2):
//   bit 0     "same as left" / "same as above" flags before each value
//   bits 1-2  literal: 0 bit tree, 1 difference to a prediction, 2 the value as an integer
//   bits 3-4  prediction (literal 1): 0 left (else above), 1 above (else left), 2 median edge detector,
//             3 slope (2 left - second left)
//   bit 5     separate flag and literal models per column (rows of at most kMaxColumnContexts values)
//   bit 6     separate difference models per activity class of the neighbourhood (literal 1)
enum Literal : uint8_t { Tree = 0, Delta = 1, Plain = 2 };
enum Prediction : uint8_t { Left = 0, Above = 1, Median = 2, Slope = 3 };
constexpr size_t kActivityClasses = 4;
constexpr uint8_t kModels = 128;
constexpr uint64_t kMaxColumnContexts = 16;
constexpr int kMaxColumnTreeBits = 12;
// The writer tries every model on fields of up to 2 kTrialValues values; on longer ones only the
// kFinalists best on the first kTrialValues values.
constexpr uint64_t kTrialValues = 8192;
constexpr size_t kFinalists = 4;

bool valid_model(uint8_t model, int w, uint64_t cols) {
  const unsigned literal = (model >> 1) & 3, prediction = (model >> 3) & 3;
  const bool per_column = (model >> 5) & 1, by_activity = (model >> 6) & 1;
  if (model >= kModels || literal > Plain) return false;
  if (literal != Delta && (prediction != 0 || by_activity)) return false;
  if (per_column && (cols < 2 || cols > kMaxColumnContexts || (literal == Tree && w > kMaxColumnTreeBits))) return false;
  return true;
}

uint32_t mask_of(int w) { return w >= 32 ? 0xFFFFFFFFu : (1u << w) - 1; }

// Bits [pos, pos + w) of an LSB-first bit stream (docs/format.md "Bit packing order").
uint32_t get_bits(const uint8_t* p, uint64_t pos, int w) {
  uint64_t v = 0;
  const uint64_t first = pos / 8, last = (pos + uint64_t(w) - 1) / 8;
  for (uint64_t b = last + 1; b-- > first;) v = (v << 8) | p[b];
  return uint32_t(v >> (pos % 8)) & mask_of(w);
}

void put_bits(uint8_t* p, uint64_t pos, int w, uint32_t v) {
  for (int k = 0; k < w;) {
    const uint64_t at = pos + uint64_t(k);
    const int shift = int(at % 8), take = std::min(8 - shift, w - k);
    p[at / 8] = uint8_t(p[at / 8] | (((v >> k) & mask_of(take)) << shift));
    k += take;
  }
}

// The literal models of one field; a value of more than 16 bits is a tree over its top bits and one
// over each of its two low bytes.
struct Models {
  Models(int w, size_t contexts)
      : w(w), same_left(6 * contexts), same_above(3 * contexts), top(contexts, SymbolModel(w > 16 ? w - 16 : w)), mid(8), low(8), integer(2 * kActivityClasses * contexts) {
  }
  int w;
  std::vector<BitModel> same_left;   // per (context, state, above equals left)
  std::vector<BitModel> same_above;  // per (context, state)
  std::vector<SymbolModel> top;  // per context (column)
  SymbolModel mid, low;
  std::vector<IntegerModel> integer;  // per (context, activity class, whether a neighbour predicts the value)
};

struct EncodeSide {
  RangeEncoder& rc;
  unsigned bit(BitModel& p, unsigned b) {
    rc.bit(p, b);
    return b;
  }
  uint32_t symbol(SymbolModel& m, uint32_t v) {
    m.encode(rc, v);
    return v;
  }
  uint32_t integer(IntegerModel& m, uint32_t v) {
    m.encode(rc, v);
    return v;
  }
};

struct DecodeSide {
  RangeDecoder& rc;
  unsigned bit(BitModel& p, unsigned) { return rc.bit(p); }
  uint32_t symbol(SymbolModel& m, uint32_t) { return m.decode(rc); }
  uint32_t integer(IntegerModel& m, uint32_t) { return m.decode(rc); }
};

uint32_t zigzag(uint32_t d, int w) {
  // d is a difference modulo 2^w; as a signed w-bit number, interleaved 0, -1, 1, -2, ...
  const uint32_t m = mask_of(w), half = w >= 32 ? 0x80000000u : (1u << (w - 1));
  d &= m;
  return d < half ? 2 * d : 2 * (m - d) + 1;
}

uint32_t unzigzag(uint32_t z, int w) {
  const uint32_t m = mask_of(w);
  return (z & 1) ? (m - (z >> 1)) & m : (z >> 1) & m;
}

// Codes the `count` w-bit values of a packed field in `bits` (the encoder reads them, the decoder
// writes them): the same walk on both sides, so each value sees the same neighbours.
template <class Side>
void code_field(Side& side, uint8_t* bits, uint64_t count, uint64_t cols, int w, uint8_t model,
                RangeDecoder* checker) {
  const bool flags = model & 1, per_column = (model >> 5) & 1, by_activity = (model >> 6) & 1;
  const Literal literal = Literal((model >> 1) & 3);
  const Prediction prediction = Prediction((model >> 3) & 3);
  Models m(w, per_column ? size_t(cols) : 1);
  constexpr bool decoding = std::is_same_v<Side, DecodeSide>;
  unsigned state = 2;  // how the previous value was coded: 0 same as left, 1 same as above, 2 literal
  for (uint64_t i = 0; i < count; ++i) {
    const bool has_left = i % cols != 0, has_above = i >= cols;
    const uint32_t left = has_left ? get_bits(bits, (i - 1) * uint64_t(w), w) : 0;
    const uint32_t above = has_above ? get_bits(bits, (i - cols) * uint64_t(w), w) : 0;
    const size_t ctx = per_column ? size_t(i % cols) : 0;
    const uint32_t truth = decoding ? 0 : get_bits(bits, i * uint64_t(w), w);
    uint32_t v = 0;
    bool done = false;
    if (flags && has_left) {
      const size_t flag_ctx = ctx * 6 + state * 2 + (has_above && above == left ? 1 : 0);
      if (side.bit(m.same_left[flag_ctx], truth == left)) {
        v = left;
        done = true;
        state = 0;
      }
    }
    if (flags && !done && has_above && !(has_left && above == left)) {
      if (side.bit(m.same_above[ctx * 3 + state], truth == above)) {
        v = above;
        done = true;
        state = 1;
      }
    }
    if (!done) {
      state = 2;
      switch (literal) {
        case Tree:
          if (w > 16) {
            v = side.symbol(m.top[0], truth >> 16) << 16;
            v |= side.symbol(m.mid, (truth >> 8) & 0xFF) << 8;
            v |= side.symbol(m.low, truth & 0xFF);
          } else {
            v = side.symbol(m.top[ctx], truth);
          }
          break;
        case Delta: {
          uint32_t predicted = 0;
          const bool has_second = i % cols >= 2;
          const uint32_t second = has_second ? get_bits(bits, (i - 2) * uint64_t(w), w) : 0;
          if (has_second && prediction == Slope) {
            const int64_t p = 2 * int64_t(left) - int64_t(second);
            predicted = uint32_t(std::clamp<int64_t>(p, 0, int64_t(mask_of(w))));
          } else if (has_left && has_above && prediction == Median) {
            const uint32_t corner = get_bits(bits, (i - cols - 1) * uint64_t(w), w);
            const uint32_t lo = std::min(left, above), hi = std::max(left, above);
            predicted = corner >= hi ? lo : corner <= lo ? hi : uint32_t((uint64_t(left) + above - corner) & mask_of(w));
          } else if (has_left && (prediction != Above || !has_above)) {
            predicted = left;
          } else if (has_above) {
            predicted = above;
          }
          const bool predicts = has_left || has_above;
          // How busy the neighbourhood is: differences there are likely as large here.
          const uint32_t activity = has_second ? (left > second ? left - second : second - left)
                                    : (has_left && has_above) ? (left > above ? left - above : above - left)
                                                              : 0;
          const size_t cls = !by_activity || activity == 0 ? 0 : activity < 4 ? 1 : activity < 32 ? 2 : 3;
          IntegerModel& im = m.integer[(ctx * kActivityClasses + cls) * 2 + predicts];
          v = (predicted + unzigzag(side.integer(im, zigzag(truth - predicted, w)), w)) & mask_of(w);
          break;
        }
        case Plain:
          v = side.integer(m.integer[ctx * kActivityClasses * 2], truth);
          if constexpr (decoding)
            if (v > mask_of(w)) checker->fail("a value wider than its field");
          break;
      }
    }
    if constexpr (decoding) put_bits(bits, i * uint64_t(w), w, v);
  }
}

// Where the fields of a packed section are, read from their headers.
struct FieldLayout {
  uint64_t header_at = 0;  // offset of the field header in the stored bytes
  uint64_t header = 0;     // field header bytes (1 for an index field, 10 for a value field)
  int width = 0;           // bits per value
  uint64_t bytes = 0;      // packed value bytes after the header
  uint8_t model = 0;
  uint64_t stream_at = 0, stream_length = 0;
};

void put_varint(std::vector<uint8_t>& out, uint64_t v) {
  for (; v >= 0x80; v >>= 7) out.push_back(uint8_t(v | 0x80));
  out.push_back(uint8_t(v));
}

// Width of the values of a field from its header at p (n bytes available); 0 if invalid.
int field_width(const FieldShape& f, const uint8_t* p, size_t n) {
  if (f.kind == FieldShape::Index) return n >= 1 && p[0] >= 1 && p[0] <= 32 ? p[0] : 0;
  if (n < 10) return 0;
  const uint8_t mode = p[0], bits = p[1];
  if (mode == 0) return bits == 32 ? 32 : 0;
  return (mode == 1 || mode == 2) && (bits == 8 || bits == 16) ? bits : 0;
}

uint64_t header_of(const FieldShape& f) { return f.kind == FieldShape::Index ? 1 : 10; }

std::optional<std::vector<uint8_t>> encode_unchecked(const std::vector<uint8_t>& raw, const SectionShape& shape,
                                                     int only_model) {
  if (shape.header_bytes > raw.size()) return std::nullopt;
  std::vector<uint8_t> out(raw.begin(), raw.begin() + long(shape.header_bytes));
  uint64_t pos = shape.header_bytes;
  std::vector<uint8_t> field;
  for (const FieldShape& f : shape.fields) {
    const uint64_t h = header_of(f);
    if (f.cols == 0 || raw.size() - pos < h) return std::nullopt;
    const int w = field_width(f, raw.data() + pos, size_t(raw.size() - pos));
    if (w == 0 || f.count > (raw.size() - pos - h) * 8 / uint64_t(w)) return std::nullopt;
    const uint64_t bytes = (f.count * uint64_t(w) + 7) / 8;
    out.insert(out.end(), raw.begin() + long(pos), raw.begin() + long(pos + h));
    pos += h;
    field.assign(raw.begin() + long(pos), raw.begin() + long(pos + bytes));
    pos += bytes;
    std::vector<uint8_t> candidates;
    for (uint8_t model = 0; model < kModels; ++model) {
      if (!valid_model(model, w, f.cols)) continue;
      if (only_model >= 0 && model != (valid_model(uint8_t(only_model), w, f.cols) ? only_model : 0)) continue;
      candidates.push_back(model);
    }
    auto coded_size = [&](uint8_t model, uint64_t count, std::vector<uint8_t>& stream) {
      stream.clear();
      RangeEncoder rc(stream);
      EncodeSide side{rc};
      code_field(side, field.data(), count, f.cols, w, model, nullptr);
      rc.finish();
      return stream.size();
    };
    std::vector<uint8_t> stream, best;
    // A long field: rank the models on its first kTrialValues values, code it whole with the best few
    // (the same choice on every run: this only saves the writer time).
    if (f.count > 2 * kTrialValues && candidates.size() > kFinalists) {
      std::vector<std::pair<size_t, uint8_t>> ranked;
      for (uint8_t model : candidates) ranked.push_back({coded_size(model, kTrialValues, stream), model});
      std::stable_sort(ranked.begin(), ranked.end());
      candidates.clear();
      for (size_t k = 0; k < kFinalists; ++k) candidates.push_back(ranked[k].second);
      std::sort(candidates.begin(), candidates.end());
    }
    uint8_t best_model = 0;
    for (uint8_t model : candidates) {
      coded_size(model, f.count, stream);
      if (best.empty() || stream.size() < best.size()) {
        best.swap(stream);
        best_model = model;
      }
    }
    out.push_back(best_model);
    if (&f != &shape.fields.back()) put_varint(out, best.size());  // the last stream ends the section
    out.insert(out.end(), best.begin(), best.end());
  }
  if (pos != raw.size()) return std::nullopt;
  return out;
}

}  // namespace

std::optional<std::vector<uint8_t>> model_encode(const std::vector<uint8_t>& raw, const SectionShape& shape,
                                                 int only_model) {
  auto out = encode_unchecked(raw, shape, only_model);
  if (!out) return out;
  // Padding bits or anything else the model cannot reproduce: store the section another way.
  try {
    if (model_decode(out->data(), out->size(), shape, raw.size(), "check") != raw) return std::nullopt;
  } catch (const CorruptError&) {
    return std::nullopt;
  }
  return out;
}

std::vector<uint8_t> model_decode(const uint8_t* stored, size_t n, const SectionShape& shape, uint64_t raw_length,
                                  const std::string& where) {
  auto fail = [&](const std::string& what) { throw CorruptError(where + ": " + what); };
  if (shape.header_bytes > n || shape.header_bytes > raw_length) fail("the section header does not fit");
  // First the sizes of everything, from the field headers, before allocating the output.
  uint64_t in = shape.header_bytes, out_size = shape.header_bytes;
  std::vector<FieldLayout> layout;
  for (size_t i = 0; i < shape.fields.size(); ++i) {
    const FieldShape& f = shape.fields[i];
    FieldLayout l;
    l.header_at = in;
    l.header = header_of(f);
    if (n - in < l.header + 1) fail("truncated field header");
    l.width = field_width(f, stored + in, size_t(n - in));
    if (l.width == 0) fail("unknown field coding");
    if (f.cols == 0 || f.count > (raw_length - std::min(raw_length, out_size + l.header)) * 8 / uint64_t(l.width))
      fail("field of " + std::to_string(f.count) + " values does not fit the section's raw length");
    l.bytes = (f.count * uint64_t(l.width) + 7) / 8;
    out_size += l.header + l.bytes;
    in += l.header;
    l.model = stored[in++];
    if (!valid_model(l.model, l.width, f.cols)) fail("unknown symbol model " + std::to_string(l.model));
    if (i + 1 == shape.fields.size()) {
      l.stream_length = n - in;
    } else {
      for (int shift = 0;; shift += 7) {
        if (in >= n || shift > 28) fail("invalid stream length");
        const uint8_t b = stored[in++];
        l.stream_length |= uint64_t(b & 0x7F) << shift;
        if (!(b & 0x80)) break;
      }
      if (l.stream_length > n - in) fail("a field stream runs past the section");
    }
    l.stream_at = in;
    in += l.stream_length;
    layout.push_back(l);
  }
  if (in != n) fail(std::to_string(n - in) + " bytes after the last field");
  if (out_size != raw_length) fail("fields decode to " + std::to_string(out_size) + " bytes, the table says " + std::to_string(raw_length));

  std::vector<uint8_t> raw(size_t(raw_length), 0);
  std::memcpy(raw.data(), stored, size_t(shape.header_bytes));
  out_size = shape.header_bytes;
  for (size_t i = 0; i < layout.size(); ++i) {
    const FieldLayout& l = layout[i];
    std::memcpy(raw.data() + out_size, stored + l.header_at, size_t(l.header));
    out_size += l.header;
    RangeDecoder rc(stored + l.stream_at, size_t(l.stream_length), where + ": field " + std::to_string(i));
    DecodeSide side{rc};
    code_field(side, raw.data() + out_size, shape.fields[i].count, shape.fields[i].cols, l.width, l.model, &rc);
    rc.finish();
    out_size += l.bytes;
  }
  return raw;
}

}  // namespace btfvq
