// btfvq: the command-line tool. Each subcommand is a thin shell over one pipeline (or HTTP) call;
// this file only dispatches and maps errors to exit codes in one place.
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <cstdio>
#include <cstdlib>
#include <exception>
#include <iostream>
#include <string>
#include <vector>

#include "client/cli.h"
#include <btfvq/error.h>

namespace {

void print_usage() {
  std::cout << "btfvq: compress measured BTFs with multi-level vector quantization\n\nusage:\n";
  for (const auto& [name, c] : btfvq::cli::registry()) std::cout << "  btfvq " << c.usage << "\n      " << c.summary << "\n";
  std::cout << "\n`btfvq COMMAND --help` (or `btfvq help COMMAND`) describes a command's options.\n"
               "\nenvironment: BTFVQ_DEVICE=auto|opencl|cpu-reference, BTFVQ_LOG=info|debug|warn\n"
               "             BTFVQ_SERVER=URL, BTFVQ_TOKEN=TOKEN (remote commands)\n";
}

bool asks_for_help(const std::string& word) { return word == "--help" || word == "-h" || word == "help"; }

// Exit codes: 0 ok, 1 internal or device failure, 2 bad input or usage, 3 corrupt data, 4 not found.
int exit_code_for(const btfvq::Error& e) {
  if (dynamic_cast<const btfvq::InputError*>(&e)) return 2;
  if (dynamic_cast<const btfvq::CorruptError*>(&e)) return 3;
  if (dynamic_cast<const btfvq::NotFoundError*>(&e)) return 4;
  return 1;
}

int run(const btfvq::cli::Command& command, const std::vector<std::string>& argv) {
  const btfvq::ArgSpec spec = btfvq::cli::spec_of(command);
  const btfvq::Args args = btfvq::parse_args(spec, argv);
  if (args.has("help")) {
    std::cout << btfvq::help_text(spec);
    return 0;
  }
  return command.run(args);
}

}  // namespace

int main(int argc, char** argv) {
  spdlog::set_default_logger(spdlog::stderr_color_mt("btfvq"));
  spdlog::set_pattern("btfvq: %l: %v");
  spdlog::set_level(spdlog::level::warn);
  if (const char* level = std::getenv("BTFVQ_LOG")) spdlog::set_level(spdlog::level::from_str(level));

  std::vector<std::string> words(argv + 1, argv + argc);
  // `btfvq help CMD` is `btfvq CMD --help`.
  if (words.size() == 2 && words[0] == "help") words = {words[1], "--help"};
  if (words.empty() || asks_for_help(words[0])) {
    print_usage();
    return words.empty() ? 2 : 0;
  }
  auto& commands = btfvq::cli::registry();
  auto it = commands.find(words[0]);
  if (it == commands.end()) {
    std::cerr << "btfvq: error: unknown command '" << words[0] << "'\n";
    print_usage();
    return 2;
  }
  try {
    return run(it->second, std::vector<std::string>(words.begin() + 1, words.end()));
  } catch (const btfvq::Error& e) {
    std::cerr << "btfvq: error: " << e.what() << "\n";
    return exit_code_for(e);
  } catch (const std::exception& e) {
    std::cerr << "btfvq: internal error: " << e.what() << "\n";
    return 1;
  }
}
