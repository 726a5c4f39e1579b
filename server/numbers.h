#pragma once
// Numbers in flags, configuration values and query parameters: the whole text must be the number,
// so that "12abc" or "" is refused rather than read as 12 or 0. Leading blanks and a '+' pass, as
// std::stoll and std::stod take them.
#include <cstdint>
#include <optional>
#include <string>

namespace btfvq::server {

std::optional<int64_t> whole_integer(const std::string& text);
std::optional<double> whole_number(const std::string& text);

}  // namespace btfvq::server
