// The one argument parser (pipeline/util/args.h) and the --help of the programs built on it, run as
// a user runs them.
#include <doctest/doctest.h>

#include <sstream>
#include <string>
#include <vector>

#include <btfvq/error.h>
#include "pipeline/util/args.h"
#include "support/test_paths.h"

using namespace btfvq;

namespace {

const ArgSpec kSpec{"demo", "demo IN... --out FILE [--size N] [--fast]", "a program for the tests",
                    {{"out", "FILE", "where to write"}, "size"}, {{"fast", "", "go fast"}}};

std::string run(const std::string& program_and_args, int* status = nullptr) {
  std::string out;
  const int s = test::run_command((test::bin_dir() / program_and_args).string(), &out);
  if (status) *status = s;
  return out;
}

// The command names `btfvq --help` lists ("  btfvq NAME ...").
std::vector<std::string> listed_commands(const std::string& help) {
  std::vector<std::string> names;
  std::istringstream lines(help);
  for (std::string line; std::getline(lines, line);)
    if (line.rfind("  btfvq ", 0) == 0) names.push_back(line.substr(8, line.find(' ', 8) - 8));
  return names;
}

}  // namespace

TEST_CASE("values, switches and positionals, in any order; the last value of an option wins") {
  const Args a = parse_args(kSpec, {"x", "--out", "a.bin", "--fast", "--size=3", "y", "--out=b.bin"});
  CHECK(a.positional == std::vector<std::string>{"x", "y"});
  CHECK(a.require("out") == "b.bin");
  CHECK(a.all("out") == std::vector<std::string>{"a.bin", "b.bin"});
  CHECK(a.integer("size", 0, 1, 9) == 3);
  CHECK(a.has("fast"));
  CHECK_FALSE(a.has("help"));
  CHECK(a.get_or("missing", "d") == "d");
  CHECK(parse_args(kSpec, {"--out="}).require("out").empty());
}

TEST_CASE("a bad argument is an InputError naming the option and the program") {
  CHECK_THROWS_WITH_AS(parse_args(kSpec, {"--foo"}),
                       "unknown option --foo for 'demo' (usage: demo IN... --out FILE [--size N] [--fast])", InputError);
  CHECK_THROWS_WITH_AS(parse_args(kSpec, {"--out"}), "--out needs a value", InputError);
  CHECK_THROWS_WITH_AS(parse_args(kSpec, {"--fast=1"}), "--fast takes no value", InputError);
  CHECK_THROWS_WITH_AS(parse_args(kSpec, {}).require("out"), "missing --out", InputError);
  CHECK_THROWS_WITH_AS(parse_args(kSpec, {"--size", "x"}).integer("size", 0, 1, 9),
                       "--size must be an integer in [1, 9] (got 'x')", InputError);
  CHECK_THROWS_WITH_AS(parse_args(kSpec, {"--size", "2x"}).integer("size", 0), "--size must be an integer (got '2x')",
                       InputError);
  ArgSpec no_words = kSpec;
  no_words.positionals = false;
  CHECK_THROWS_AS(parse_args(no_words, {"x"}), InputError);
}

TEST_CASE("--help or -h anywhere asks for help, even among bad arguments") {
  for (const char* help : {"--help", "-h"}) {
    const Args a = parse_args(kSpec, {"--foo", "x", help, "--out"});
    CHECK(a.has("help"));
    CHECK(a.positional.empty());
  }
  const std::string text = help_text(kSpec);
  CHECK(text.find("demo: a program for the tests") == 0);
  CHECK(text.find("usage: demo IN... --out FILE") != std::string::npos);
  CHECK(text.find("--out FILE") != std::string::npos);
  CHECK(text.find("where to write") != std::string::npos);
  CHECK(text.find("--size SIZE") != std::string::npos);  // no value name given: the option name in capitals
  CHECK(text.find("--fast") != std::string::npos);
  CHECK(text.find("-h, --help") != std::string::npos);
}

TEST_CASE("btfvq --help, -h and help list every command; each command's --help shows its usage and options") {
  int status = -1;
  const std::string list = run("btfvq --help", &status);
  CHECK(status == 0);
  const auto names = listed_commands(list);
  CHECK(names.size() >= 14);
  CHECK(run("btfvq -h", &status) == list);
  CHECK(status == 0);
  CHECK(run("btfvq help", &status) == list);
  CHECK(status == 0);
  for (const auto& name : names) {
    CAPTURE(name);
    const std::string help = run("btfvq " + name + " --help", &status);
    CHECK(status == 0);
    CHECK(help.find("btfvq " + name + ": ") == 0);
    CHECK(help.find("usage: btfvq " + name) != std::string::npos);
    CHECK(help.find("-h, --help") != std::string::npos);
    CHECK(run("btfvq " + name + " -h") == help);
    CHECK(run("btfvq help " + name) == help);
  }
  const std::string render = run("btfvq render --help");
  for (const char* option : {"--material NAME", "--scene sphere|plane", "--size N", "--env"})
    CHECK(render.find(option) != std::string::npos);
}

TEST_CASE("btfvq rejects an unknown option with status 2 and names the command") {
  int status = -1;
  const std::string out = run("btfvq info --bogus x", &status);
  CHECK(status == 2);
  CHECK(out.find("unknown option --bogus for 'btfvq info'") != std::string::npos);
  CHECK(run("btfvq nosuch", &status).find("unknown command 'nosuch'") != std::string::npos);
  CHECK(status == 2);
}

TEST_CASE("btfvq-server --help lists its options; a stray argument is refused before it starts") {
  int status = -1;
  const std::string help = run("btfvq-server --help", &status);
  CHECK(status == 0);
  for (const char* option : {"--listen HOST:PORT", "--data DIR", "--config FILE", "--input-root DIR", "--workers N"})
    CHECK(help.find(option) != std::string::npos);
  CHECK(run("btfvq-server stray", &status).find("unexpected argument 'stray' for 'btfvq-server'") != std::string::npos);
  CHECK(status == 2);
  CHECK(run("btfvq-server --workers", &status).find("--workers needs a value") != std::string::npos);
  CHECK(status == 2);
}
