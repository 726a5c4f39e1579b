#include "pipeline/util/args.h"

#include <algorithm>
#include <cctype>

#include <btfvq/error.h>

namespace btfvq {
namespace {

bool declares(const std::vector<Option>& options, const std::string& name) {
  return std::any_of(options.begin(), options.end(), [&](const Option& o) { return o.name == name; });
}

bool asks_for_help(const std::vector<std::string>& argv) {
  return std::any_of(argv.begin(), argv.end(), [](const std::string& a) { return a == "--help" || a == "-h"; });
}

// `--name` or `--name=value`, split; nullopt for a positional.
struct Flag {
  std::string name;
  std::optional<std::string> value;
};

std::optional<Flag> as_flag(const std::string& word) {
  if (word.rfind("--", 0) != 0 || word == "--") return std::nullopt;
  const auto eq = word.find('=');
  if (eq == std::string::npos) return Flag{word.substr(2), std::nullopt};
  return Flag{word.substr(2, eq - 2), word.substr(eq + 1)};
}

// The value's name printed after an option in --help: the spec's, else the option's name in capitals.
std::string value_name(const Option& o) {
  if (!o.value.empty()) return o.value;
  std::string upper = o.name;
  for (char& c : upper) c = char(std::toupper(static_cast<unsigned char>(c)));
  return upper;
}

std::string usage_line(const ArgSpec& spec) { return "usage: " + spec.usage; }

std::string option_lines(const std::vector<std::pair<std::string, std::string>>& rows) {
  size_t width = 0;
  for (const auto& [left, help] : rows) width = std::max(width, left.size());
  std::string out;
  for (const auto& [left, help] : rows)
    out += "  " + left + (help.empty() ? "" : std::string(width - left.size() + 2, ' ') + help) + "\n";
  return out;
}

}  // namespace

const std::vector<std::string>& Args::all(const std::string& flag) const {
  static const std::vector<std::string> none;
  auto it = values_.find(flag);
  return it == values_.end() ? none : it->second;
}

std::optional<std::string> Args::get(const std::string& flag) const {
  const auto& given = all(flag);
  if (given.empty()) return std::nullopt;
  return given.back();
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
  if (used == v->size() && n >= lo && n <= hi) return int(n);
  if (lo == INT_MIN && hi == INT_MAX) throw InputError("--" + flag + " must be an integer (got '" + *v + "')");
  throw InputError("--" + flag + " must be an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) +
                   "] (got '" + *v + "')");
}

Args parse_args(const ArgSpec& spec, const std::vector<std::string>& argv) {
  Args args;
  if (asks_for_help(argv)) {
    args.add("help", "1");
    return args;
  }
  const std::string usage = " (" + usage_line(spec) + ")";
  for (size_t i = 0; i < argv.size(); ++i) {
    const auto flag = as_flag(argv[i]);
    if (!flag) {
      if (!spec.positionals) throw InputError("unexpected argument '" + argv[i] + "' for '" + spec.program + "'" + usage);
      args.positional.push_back(argv[i]);
    } else if (declares(spec.values, flag->name)) {
      if (!flag->value && i + 1 >= argv.size()) throw InputError("--" + flag->name + " needs a value");
      args.add(flag->name, flag->value ? *flag->value : argv[++i]);
    } else if (!declares(spec.switches, flag->name)) {
      throw InputError("unknown option --" + flag->name + " for '" + spec.program + "'" + usage);
    } else if (flag->value) {
      throw InputError("--" + flag->name + " takes no value");
    } else {
      args.add(flag->name, "1");
    }
  }
  return args;
}

std::string help_text(const ArgSpec& spec) {
  std::vector<std::pair<std::string, std::string>> rows;
  for (const auto& o : spec.values) rows.emplace_back("--" + o.name + " " + value_name(o), o.help);
  for (const auto& o : spec.switches) rows.emplace_back("--" + o.name, o.help);
  rows.emplace_back("-h, --help", "print this help");
  std::string out = spec.program + ": " + spec.summary + "\n\n" + usage_line(spec) + "\n\noptions:\n" + option_lines(rows);
  if (!spec.notes.empty()) out += "\n" + spec.notes + "\n";
  return out;
}

}  // namespace btfvq
