#pragma once
// The command-line shell: each subcommand lives in its own client/cmd_*.cpp, registers itself with
// a static CommandRegistrar, and turns flags into options for one pipeline call.
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <btfvq/directions.h>
#include <btfvq/error.h>

namespace btfvq::cli {

// Parsed arguments of one subcommand. Flags are `--name value` or `--name=value`; switches are
// `--name`. Unknown flags are an error (a misspelled flag must not be silently ignored).
class Args {
 public:
  std::vector<std::string> positional;

  bool has(const std::string& flag) const { return values_.count(flag) > 0; }
  // Every value given for a repeatable flag, in order.
  const std::vector<std::string>& all(const std::string& flag) const;
  std::optional<std::string> get(const std::string& flag) const;
  std::string get_or(const std::string& flag, const std::string& fallback) const;
  std::string require(const std::string& flag) const;  // throws InputError when absent
  int integer(const std::string& flag, int fallback, int lo, int hi) const;

  void add(const std::string& flag, const std::string& value) { values_[flag].push_back(value); }

 private:
  std::map<std::string, std::vector<std::string>> values_;
};

struct Command {
  std::string name;
  std::string usage;                     // one line, after "btfvq "
  std::string summary;                   // one sentence for the command list
  std::vector<std::string> value_flags;  // flags that take a value, without "--"
  std::vector<std::string> switches;     // flags without a value
  std::function<int(const Args&)> run;
};

std::map<std::string, Command>& registry();

struct CommandRegistrar {
  explicit CommandRegistrar(Command c);
};

// "THETA,PHI" in degrees, e.g. "45,120"; theta in [0, 90]. Throws InputError naming the flag.
Direction parse_direction(const std::string& text, const std::string& flag);

// The material name an input path stands for: "path/UBO_IMPALLA256.zip" -> "UBO_IMPALLA256".
std::string material_name_of(const std::string& input_path);

// Parses argv (after the subcommand name) against a command's declared flags.
Args parse_args(const Command& command, const std::vector<std::string>& argv);

}  // namespace btfvq::cli
