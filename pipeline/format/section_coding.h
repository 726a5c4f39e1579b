#pragma once
// Section encoding 2 of the .btfdb format (docs/format.md, "Section encodings"): the packed fields of
// a section re-coded symbol by symbol with an adaptive binary range coder. Bit packing hides the
// structure a general-purpose compressor would need (values straddle bytes), so this coder reads the
// values back out of their fields and models each one against its neighbours in the table or image:
// equal to the value on the left, equal to the value above, or a literal (a full bit tree, or the
// difference to a prediction: left, above, median edge detector or slope, as a variable-length
// integer, optionally with models per column and per neighbourhood activity). The encoder tries each
// model per field and keeps the smallest; the decoded bytes are exactly the packed section.
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace btfvq {

// One packed field of a section (docs/format.md "Fields inside sections").
struct FieldShape {
  enum Kind : uint8_t { Index, Values } kind = Index;
  uint64_t count = 0;  // values in the field
  uint64_t cols = 1;   // values per row: the value above a value is `cols` positions before it
};

// A section: `header_bytes` leading bytes, then its fields in order.
struct SectionShape {
  uint64_t header_bytes = 0;
  std::vector<FieldShape> fields;
};

// The stored bytes of encoding 2 for the packed section `raw`; nothing if `raw` does not have the
// given shape (the caller then stores another encoding). Each field gets the symbol model that codes
// it smallest; `only_model` >= 0 forces that model on every field where it is valid (for tests).
std::optional<std::vector<uint8_t>> model_encode(const std::vector<uint8_t>& raw, const SectionShape& shape,
                                                 int only_model = -1);

// The packed section back from stored bytes. Anything inconsistent (sizes that do not add up to
// raw_length, an unknown model, a damaged range coder stream) throws CorruptError naming `where`;
// nothing is allocated beyond raw_length.
std::vector<uint8_t> model_decode(const uint8_t* stored, size_t n, const SectionShape& shape, uint64_t raw_length,
                                  const std::string& where);

}  // namespace btfvq
