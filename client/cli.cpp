#include "client/cli.h"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include <btfvq/error.h>

namespace btfvq::cli {

std::map<std::string, Command>& registry() {
  static std::map<std::string, Command> commands;
  return commands;
}

CommandRegistrar::CommandRegistrar(Command c) { registry()[c.name] = std::move(c); }

const std::vector<std::string>& Args::all(const std::string& flag) const {
  static const std::vector<std::string> none;
  auto it = values_.find(flag);
  return it == values_.end() ? none : it->second;
}

std::optional<std::string> Args::get(const std::string& flag) const {
  auto it = values_.find(flag);
  if (it == values_.end() || it->second.empty()) return std::nullopt;
  return it->second.back();
}

std::string Args::get_or(const std::string& flag, const std::string& fallback) const {
  auto v = get(flag);
  return v ? *v : fallback;
}

std::string Args::require(const std::string& flag) const {
  auto v = get(flag);
  if (!v) throw InputError("missing --" + flag);
  return *v;
}

int Args::integer(const std::string& flag, int fallback, int lo, int hi) const {
  auto v = get(flag);
  if (!v) return fallback;
  size_t used = 0;
  long long n = 0;
  try {
    n = std::stoll(*v, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != v->size() || n < lo || n > hi)
    throw InputError("--" + flag + " must be an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) +
                     "] (got '" + *v + "')");
  return int(n);
}

std::string material_name_of(const std::string& input_path) {
  std::filesystem::path p(input_path);
  while (!p.empty() && p.filename().empty()) p = p.parent_path();
  std::string name = p.filename().string();
  if (name.size() > 4 && name.substr(name.size() - 4) == ".zip") name.resize(name.size() - 4);
  return name;
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

Args parse_args(const Command& command, const std::vector<std::string>& argv) {
  Args args;
  auto takes_value = [&](const std::string& f) {
    return std::find(command.value_flags.begin(), command.value_flags.end(), f) != command.value_flags.end();
  };
  auto is_switch = [&](const std::string& f) {
    return std::find(command.switches.begin(), command.switches.end(), f) != command.switches.end();
  };
  for (size_t i = 0; i < argv.size(); ++i) {
    const std::string& a = argv[i];
    if (a.rfind("--", 0) != 0 || a == "--") {
      args.positional.push_back(a);
      continue;
    }
    std::string flag = a.substr(2), value;
    const auto eq = flag.find('=');
    const bool inline_value = eq != std::string::npos;
    if (inline_value) {
      value = flag.substr(eq + 1);
      flag = flag.substr(0, eq);
    }
    if (takes_value(flag)) {
      if (!inline_value) {
        if (i + 1 >= argv.size()) throw InputError("--" + flag + " needs a value");
        value = argv[++i];
      }
      args.add(flag, value);
    } else if (is_switch(flag) && !inline_value) {
      args.add(flag, "1");
    } else {
      throw InputError("unknown option --" + flag + " for 'btfvq " + command.name + "' (usage: btfvq " +
                       command.usage + ")");
    }
  }
  return args;
}

}  // namespace btfvq::cli
