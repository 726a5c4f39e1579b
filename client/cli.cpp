#include "client/cli.h"

#include <cmath>
#include <filesystem>
#include <sstream>

#include <btfvq/error.h>

namespace btfvq::cli {

std::map<std::string, Command>& registry() {
  static std::map<std::string, Command> commands;
  return commands;
}

CommandRegistrar::CommandRegistrar(Command c) { registry()[c.name] = std::move(c); }

std::string material_name_of(const std::string& input_path) {
  std::filesystem::path p(input_path);
  while (!p.empty() && p.filename().empty()) p = p.parent_path();
  std::string name = p.filename().string();
  if (name.size() > 4 && name.substr(name.size() - 4) == ".zip") name.resize(name.size() - 4);
  return name;
}

double parse_number(const std::string& text, const std::string& flag, double lo, double hi) {
  size_t used = 0;
  double v = std::nan("");
  try {
    v = std::stod(text, &used);
  } catch (const std::exception&) {
  }
  if (used != text.size() || !(v >= lo && v <= hi)) {
    std::ostringstream range;
    range << lo << " to " << hi;
    throw InputError(flag + ": '" + text + "' is not a number from " + range.str());
  }
  return v;
}

Direction parse_direction(const std::string& text, const std::string& flag) {
  const auto comma = text.find(',');
  double v[2] = {0, 0};
  bool ok = comma != std::string::npos;
  const std::string parts[2] = {ok ? text.substr(0, comma) : text, ok ? text.substr(comma + 1) : ""};
  for (int i = 0; ok && i < 2; ++i) {
    size_t used = 0;
    try {
      v[i] = std::stod(parts[i], &used);
    } catch (const std::exception&) {
      used = 0;
    }
    ok = used == parts[i].size() && used > 0 && std::isfinite(v[i]);
  }
  if (!ok || v[0] < 0 || v[0] > 90)
    throw InputError("--" + flag + " must be THETA,PHI in degrees with theta in [0, 90] (got '" + text + "')");
  return {v[0], v[1]};
}

ArgSpec spec_of(const Command& command) {
  return {"btfvq " + command.name, "btfvq " + command.usage, command.summary, command.value_flags, command.switches};
}

}  // namespace btfvq::cli
