#pragma once
// The command-line shell: each subcommand lives in its own client/cmd_*.cpp, registers itself with
// a static CommandRegistrar, and turns flags into options for one pipeline call.
#include <functional>
#include <map>
#include <string>
#include <vector>

#include <btfvq/directions.h>
#include <btfvq/error.h>
#include "pipeline/util/args.h"

namespace btfvq::cli {

struct Command {
  std::string name;
  std::string usage;                // one line, after "btfvq "
  std::string summary;              // one sentence for the command list and --help
  std::vector<Option> value_flags;  // options that take a value
  std::vector<Option> switches;     // options without one
  std::function<int(const Args&)> run;
};

std::map<std::string, Command>& registry();

struct CommandRegistrar {
  explicit CommandRegistrar(Command c);
};

// "THETA,PHI" in degrees, e.g. "45,120"; theta in [0, 90]. Throws InputError naming the flag.
Direction parse_direction(const std::string& text, const std::string& flag);

// A number in [lo, hi] for `flag` (the whole text), or an InputError naming the flag.
double parse_number(const std::string& text, const std::string& flag, double lo, double hi);

// The material name an input path stands for: "path/UBO_IMPALLA256.zip" -> "UBO_IMPALLA256".
std::string material_name_of(const std::string& input_path);

// What parse_args checks a command's arguments against, and what its --help shows.
ArgSpec spec_of(const Command& command);

}  // namespace btfvq::cli
