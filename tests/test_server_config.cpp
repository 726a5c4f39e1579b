// btfvq-server's configuration (server/server_config.cpp): the shipped defaults and the range
// checks of the keys, read from real files as --config reads them.
#include <doctest/doctest.h>

#include <filesystem>
#include <fstream>

#include <btfvq/error.h>
#include "server/server_config.h"
#include "support/test_paths.h"

using namespace btfvq;

namespace {

server::ServerConfig load(const std::string& json_text) {
  const auto file = test::scratch_dir("server-config") / "server.json";
  std::ofstream(file) << json_text;
  server::ServerFlags flags;
  flags.config_file = file.string();
  return server::load_server_config(flags);
}

std::string refusal(const std::string& json_text) {
  try {
    load(json_text);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST_CASE("upload_abandon_after_s: a day by default, 1 s to 366 days, whole seconds") {
  CHECK(server::load_server_config({}).service.upload_abandon_after_s == 86400);
  CHECK(server::ServiceConfig{}.upload_abandon_after_s == 86400);  // the struct agrees with the shipped file
  CHECK(load(R"({"upload_abandon_after_s": 1})").service.upload_abandon_after_s == 1);
  CHECK(load(R"({"upload_abandon_after_s": 31622400})").service.upload_abandon_after_s == 31622400);
  for (const std::string bad : {R"({"upload_abandon_after_s": 0})", R"({"upload_abandon_after_s": 31622401})",
                                R"({"upload_abandon_after_s": -5})", R"({"upload_abandon_after_s": 1.5})",
                                R"({"upload_abandon_after_s": "1h"})"}) {
    CAPTURE(bad);
    CHECK(refusal(bad).find("upload_abandon_after_s") != std::string::npos);
  }
}

TEST_CASE("a misspelled server key is refused by name") {
  CHECK(refusal(R"({"upload_abandon_after": 10})").find("upload_abandon_after") != std::string::npos);
}
