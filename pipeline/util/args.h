#pragma once
// The command-line arguments of every btfvq program: the CLI's commands, btfvq-server and the
// benches. A program declares what it accepts once (ArgSpec), and that one declaration both checks
// the arguments and writes the --help text, so the two cannot disagree. Nothing here prints: a bad
// argument is an InputError naming the option and the program, and each program decides where
// errors and help go.
//
// Grammar: `--name value` or `--name=value` for an option that takes a value, `--name` for a
// switch, anything else (also "-" and "--") a positional. `--help` or `-h` stops the parse.
#include <climits>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace btfvq {

// One option. `value` names what a value option takes in --help ("FILE"; when empty, the option's
// name in capitals); a switch ignores it.
struct Option {
  // Implicit, so that a command can declare options by name alone: {"db", "config"}.
  Option(const char* name) : name(name) {}
  Option(std::string name, std::string value, std::string help)
      : name(std::move(name)), value(std::move(value)), help(std::move(help)) {}

  std::string name;  // without "--"
  std::string value;
  std::string help;  // one line
};

struct ArgSpec {
  std::string program;          // "btfvq compress", "btfvq-server", "bench_speed"
  std::string usage;            // one line, the program name first: "btfvq-server [--listen HOST:PORT]"
  std::string summary;          // one sentence
  std::vector<Option> values;   // options that take a value
  std::vector<Option> switches;
  bool positionals = true;      // false: a bare word is an error
  std::string notes;            // more lines for --help (defaults, environment)
};

// What parse_args found. Each option keeps every value it was given, in order; get() is the last.
class Args {
 public:
  std::vector<std::string> positional;

  bool has(const std::string& flag) const { return values_.count(flag) > 0; }
  const std::vector<std::string>& all(const std::string& flag) const;
  std::optional<std::string> get(const std::string& flag) const;
  std::string get_or(const std::string& flag, const std::string& fallback) const;
  std::string require(const std::string& flag) const;  // InputError when absent
  // `fallback` when absent; InputError unless the whole value is an integer in [lo, hi].
  int integer(const std::string& flag, int fallback, int lo = INT_MIN, int hi = INT_MAX) const;

  void add(const std::string& flag, const std::string& value) { values_[flag].push_back(value); }

 private:
  std::map<std::string, std::vector<std::string>> values_;
};

// argv without the program (and command) name. InputError for an unknown option, a value option
// without its value, a value given to a switch, or a positional where the spec takes none. After
// `--help` or `-h` the result holds only the switch "help", whatever else argv says.
Args parse_args(const ArgSpec& spec, const std::vector<std::string>& argv);

// What --help shows: the summary, the usage line, one line per option and the notes.
std::string help_text(const ArgSpec& spec);

}  // namespace btfvq
