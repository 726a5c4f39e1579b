// The real `btfvq-server` binary serves a PNG preview of a material it compressed:
// GET /v1/databases/{db}/materials/{name}/preview.png (docs/api.md).
#include <doctest/doctest.h>
#include <httplib.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <thread>

#include "support/image_file.h"
#include "support/server_process.h"
#include "support/test_paths.h"

using namespace btfvq::test;
namespace fs = std::filesystem;
using nlohmann::json;

TEST_CASE("GET .../materials/{name}/preview.png: the material on a sphere, lit, on a dark background") {
  const fs::path dir = scratch_dir("server-preview");
  ServerProcess server(dir / "data", free_loopback_port());
  httplib::Client c(server.url());
  c.set_read_timeout(60);
  const json job = {{"database", "shop"},
                    {"materials", json::array({{{"name", "wood8"},
                                                {"source", {{"synthetic", {{"preset", "wood"}, {"size", 8}, {"seed", 1}}}}}}})}};
  auto submitted = c.Post("/v1/jobs", job.dump(), "application/json");
  REQUIRE(submitted);
  REQUIRE(submitted->status == 202);
  const std::string id = json::parse(submitted->body)["id"];
  std::string state;
  for (int i = 0; i < 1200 && state != "succeeded" && state != "failed"; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    auto r = c.Get(("/v1/jobs/" + id).c_str());
    REQUIRE(r);
    state = json::parse(r->body)["state"];
  }
  REQUIRE(state == "succeeded");

  auto r = c.Get("/v1/databases/shop/materials/wood8/preview.png?size=96&light=30,135");
  REQUIRE(r);
  REQUIRE(r->status == 200);
  CHECK(r->get_header_value("Content-Type") == "image/png");
  const Image im = decode_image(r->body);
  REQUIRE(im.width == 96);
  REQUIRE(im.height == 96);
  REQUIRE(im.channels == 3);
  CHECK(im.at(0, 0, 1) == 40);  // background outside the sphere
  CHECK(im.at(95, 95, 1) == 40);
  // The lit side (up-left, facing the light) is brighter than the side turned away from it.
  const int lit = im.at(36, 36, 1), dark = im.at(80, 74, 1);
  CHECK(lit > 60);
  CHECK(lit > dark + 20);

  auto env = c.Get("/v1/databases/shop/materials/wood8/preview.png?size=64&env=1&scene=plane");
  REQUIRE(env);
  CHECK(env->status == 200);
  CHECK(decode_image(env->body).width == 64);

  auto missing = c.Get("/v1/databases/shop/materials/nope/preview.png");
  REQUIRE(missing);
  CHECK(missing->status == 404);
  CHECK(json::parse(missing->body)["error"]["message"].get<std::string>().find("nope") != std::string::npos);
  auto bad = c.Get("/v1/databases/shop/materials/wood8/preview.png?scene=cube");
  REQUIRE(bad);
  CHECK(bad->status == 400);
  auto no_db = c.Get("/v1/databases/none/materials/wood8/preview.png");
  REQUIRE(no_db);
  CHECK(no_db->status == 404);
}
