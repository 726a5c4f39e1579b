#include "server/numbers.h"

#include <stdexcept>

namespace btfvq::server {
namespace {

template <class T, class Parse>
std::optional<T> whole(const std::string& text, Parse parse) {
  size_t used = 0;
  T value{};
  try {
    value = parse(text, &used);
  } catch (const std::exception&) {  // not a number, or out of range
    return std::nullopt;
  }
  if (used == 0 || used != text.size()) return std::nullopt;
  return value;
}

}  // namespace

std::optional<int64_t> whole_integer(const std::string& text) {
  return whole<int64_t>(text, [](const std::string& s, size_t* used) { return std::stoll(s, used); });
}

std::optional<double> whole_number(const std::string& text) {
  return whole<double>(text, [](const std::string& s, size_t* used) { return std::stod(s, used); });
}

}  // namespace btfvq::server
