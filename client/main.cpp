// btfvq: the command-line tool. Each subcommand is a thin shell over one pipeline (or HTTP) call;
// this file only dispatches and maps errors to exit codes in one place.
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <cstdio>
#include <cstdlib>
#include <exception>
#include <iostream>

#include "client/cli.h"
#include <btfvq/error.h>

namespace {

void print_usage() {
  std::cout << "btfvq: compress measured BTFs with multi-level vector quantization\n\nusage:\n";
  for (const auto& [name, c] : btfvq::cli::registry()) std::cout << "  btfvq " << c.usage << "\n      " << c.summary << "\n";
  std::cout << "\nenvironment: BTFVQ_DEVICE=auto|opencl|cpu-reference, BTFVQ_LOG=info|debug|warn\n"
               "             BTFVQ_SERVER=URL, BTFVQ_TOKEN=TOKEN (remote commands)\n";
}

// Exit codes: 0 ok, 1 internal or device failure, 2 bad input or usage, 3 corrupt data, 4 not found.
int exit_code_for(const btfvq::Error& e) {
  if (dynamic_cast<const btfvq::InputError*>(&e)) return 2;
  if (dynamic_cast<const btfvq::CorruptError*>(&e)) return 3;
  if (dynamic_cast<const btfvq::NotFoundError*>(&e)) return 4;
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  spdlog::set_default_logger(spdlog::stderr_color_mt("btfvq"));
  spdlog::set_pattern("btfvq: %l: %v");
  spdlog::set_level(spdlog::level::warn);
  if (const char* level = std::getenv("BTFVQ_LOG")) spdlog::set_level(spdlog::level::from_str(level));

  if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "help") {
    print_usage();
    return argc < 2 ? 2 : 0;
  }
  const std::string name = argv[1];
  auto& commands = btfvq::cli::registry();
  auto it = commands.find(name);
  if (it == commands.end()) {
    std::cerr << "btfvq: error: unknown command '" << name << "'\n";
    print_usage();
    return 2;
  }
  try {
    const auto args = btfvq::cli::parse_args(it->second, std::vector<std::string>(argv + 2, argv + argc));
    return it->second.run(args);
  } catch (const btfvq::Error& e) {
    std::cerr << "btfvq: error: " << e.what() << "\n";
    return exit_code_for(e);
  } catch (const std::exception& e) {
    std::cerr << "btfvq: internal error: " << e.what() << "\n";
    return 1;
  }
}
