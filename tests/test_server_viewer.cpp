// The browser viewer (docs/viewer.md) for real: a real btfvq-server compresses leather 32 x 32 (then an
// HDR wood 16 x 16 into a second version), and
// headless Chromium (tests/viewer_browser.py, the DevTools protocol over a pipe, WebGL2 in
// SwiftShader) opens the material's viewer page, which streams the sections by HTTP Range, decodes
// them in JavaScript and draws them with the WebGL2 decoder. Checked: the plane view of each matches
// `btfvq render` of the same directions and the sphere `btfvq render --scene sphere` (mean absolute
// difference <= 2 of 255 per channel), the page fetched at most 1.1 x the bytes of the sections the
// material needs (DevTools and the server's own count), its event log shows a first picture before
// the last P6 byte arrived, and the listing page names the database and the material.
#include <doctest/doctest.h>
#include <httplib.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "pipeline/format/database.h"
#include "support/image_file.h"
#include "support/server_process.h"
#include "support/test_paths.h"

using namespace btfvq;
using namespace btfvq::test;
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

double bytes_served(const std::string& url) {
  httplib::Client c(url);
  auto r = c.Get("/metrics");
  REQUIRE(r);
  const std::string key = "\nbtfvq_bytes_served_total ";
  const auto at = r->body.find(key);
  REQUIRE(at != std::string::npos);
  return std::stod(r->body.substr(at + key.size()));
}

// Stored bytes of the sections one material needs: its own and every code-book chunk of its version
// or before (what the page must fetch, besides the head).
uint64_t needed_bytes(const fs::path& file, const std::string& material) {
  const std::string bytes = file_bytes(file);
  const auto* data = reinterpret_cast<const uint8_t*>(bytes.data());
  const DatabaseHead head = parse_head(data, bytes.size(), file.string());
  uint32_t version = 0;
  uint64_t total = 0;
  for (const SectionEntry& s : head.sections)
    if (s.kind == SectionKind::Material && s.material == material) {
      version = s.version;
      total += s.length;
    }
  REQUIRE(version > 0);
  for (const SectionEntry& s : head.sections)
    if (s.kind == SectionKind::Codebook && s.version <= version) total += s.length;
  return total;
}

// Opens `page` in headless Chromium (tests/viewer_browser.py) and returns what it recorded; the
// screenshots land in `out`. Any failure to start the browser or to finish the page fails here, with
// the script's one line.
json run_browser(const std::string& page, const fs::path& out) {
  fs::create_directories(out);
  std::string output;
  const std::string script = (fs::path(BTFVQ_SOURCE_DIR) / "tests" / "viewer_browser.py").string();
  const int status = run_command("python3 " + script + " '" + page + "' " + out.string() + " 120", &output);
  if (status != 0) FAIL("viewer_browser.py: " << output);
  return json::parse(file_bytes(out / "record.json"));
}

// Mean absolute difference per channel of `render` and the canvas sampled at the centre of each of
// its blocks (the canvas is an integer multiple of the render's size).
std::array<double, 3> mean_difference(const Image& render, const Image& canvas) {
  REQUIRE(canvas.width % render.width == 0);
  REQUIRE(canvas.width / render.width == canvas.height / render.height);
  const int block = canvas.width / render.width;
  std::array<double, 3> diff{0, 0, 0};
  for (int y = 0; y < render.height; ++y)
    for (int x = 0; x < render.width; ++x)
      for (int c = 0; c < 3; ++c)
        diff[size_t(c)] += std::abs(canvas.at(x * block + block / 2, y * block + block / 2, c) - render.at(x, y, c));
  for (double& d : diff) d /= double(render.width * render.height);
  return diff;
}

// Submits a job and waits until it is done (the job id is the last word `btfvq submit` prints, after
// any upload progress).
void run_job(const fs::path& dir, const std::string& server_args, const std::string& job_args) {
  const std::string out = btfvq_ok(dir, "submit " + server_args + " " + job_args);
  btfvq_ok(dir, "watch " + server_args + " " + out.substr(out.find_last_of(" \n") + 1));
}

}  // namespace

TEST_CASE("viewer files: the page, modules with a JavaScript type, 404 for anything else") {
  const fs::path dir = scratch_dir("viewer-files");
  ServerProcess server(dir / "data", free_loopback_port());
  httplib::Client c(server.url());
  for (const char* page : {"/viewer/", "/viewer/shop/leather"}) {
    auto r = c.Get(page);
    REQUIRE(r);
    CHECK(r->status == 200);
    CHECK(r->get_header_value("Content-Type") == "text/html; charset=utf-8");
    CHECK(r->body.find("/viewer/static/viewer.js") != std::string::npos);
  }
  for (const char* module : {"viewer.js", "streaming.js", "database.js", "range_coder.js", "renderer.js", "fzstd.js"}) {
    auto r = c.Get(std::string("/viewer/static/") + module);
    REQUIRE(r);
    CHECK(r->status == 200);
    CHECK(r->get_header_value("Content-Type") == "text/javascript; charset=utf-8");
  }
  auto css = c.Get("/viewer/static/viewer.css");
  REQUIRE(css);
  CHECK(css->get_header_value("Content-Type") == "text/css; charset=utf-8");
  auto missing = c.Get("/viewer/static/nothing.js");
  REQUIRE(missing);
  CHECK(missing->status == 404);
  CHECK(json::parse(missing->body)["error"]["code"] == "not_found");
  // No request leaves the server: no absolute URL in any file.
  for (const char* file : {"index.html", "viewer.js", "streaming.js", "database.js", "range_coder.js", "renderer.js"}) {
    auto r = c.Get(std::string("/viewer/static/") + file);
    if (std::string(file) == "index.html") r = c.Get("/viewer/");
    REQUIRE(r);
    CHECK_MESSAGE(r->body.find("http://") == std::string::npos, file);
    CHECK_MESSAGE(r->body.find("https://") == std::string::npos, file);
  }
}

TEST_CASE("viewer in headless Chromium: streams a material, draws it like btfvq render, fetches only its sections") {
  const fs::path dir = scratch_dir("viewer-browser");
  ServerProcess server(dir / "data", free_loopback_port());
  const std::string s = "--server " + server.url();
  // Version 1: leather, LDR. Version 2: an HDR wood (uploaded: synthetic jobs are LDR), whose code-book
  // rows are appended chunks: its page must put both versions' chunks together, and leather's page
  // must not fetch them.
  run_job(dir, s, "--db shop --synthetic leather:32 --name leather --seed 3");
  const fs::path wood = dir / "wood-hdr.zip";
  btfvq_ok(dir, "synth --preset wood --size 16 --hdr --seed 2 --out " + wood.string());
  run_job(dir, s, "--db shop --upload " + wood.string() + " --name wood-hdr");
  const fs::path db = dir / "shop.btfdb";
  btfvq_ok(dir, "download " + s + " shop --out " + db.string());
  // The directions of the comparison: generic ones (between grid nodes in every dimension).
  const std::string light = "35,120", view = "20,60";
  for (const char* material : {"leather", "wood-hdr"})
    btfvq_ok(dir, "render " + db.string() + " --material " + material + " --light " + light + " --view " + view + " --out " +
                 (dir / (std::string(material) + ".png")).string());

  const double served_before = bytes_served(server.url());
  const json record = run_browser(server.url() + "/viewer/shop/leather?scene=plane&light=" + light + "&view=" + view, dir / "plane");
  const double served = bytes_served(server.url()) - served_before;

  // (Plain blocks, not SUBCASEs: doctest would run the whole case, browser and all, once per subcase.)
  {  // the plane view is btfvq render's image
    const Image render = read_image(dir / "leather.png"), canvas = read_image(dir / "plane" / "canvas.png");
    REQUIRE(render.width == 32);
    REQUIRE(canvas.width == 512);
    const auto diff = mean_difference(render, canvas);
    std::printf("plane, leather: viewer vs btfvq render: mean absolute difference R %.3f G %.3f B %.3f of 255\n", diff[0], diff[1], diff[2]);
    for (double d : diff) CHECK(d <= 2.0);
  }

  {  // bytes fetched from /content: at most 1.1 x the sections the material needs
    const uint64_t needed = needed_bytes(db, "leather");
    uint64_t fetched = 0;
    for (const json& r : record["requests"])
      if (r["url"].get<std::string>().find("/content") != std::string::npos) {
        CHECK(r["status"] == 206);  // every piece by Range, never the whole file
        fetched += r["bytes"].get<uint64_t>();
      }
    std::printf("viewer fetched %llu bytes from /content (server counted %.0f) for %llu bytes of sections (file %llu)\n",
                (unsigned long long)fetched, served, (unsigned long long)needed, (unsigned long long)fs::file_size(db));
    CHECK(fetched > 0);
    CHECK(fetched < fs::file_size(db));  // wood-hdr's sections are not among them
    CHECK(double(fetched) <= 1.1 * double(needed));
    CHECK(served <= 1.1 * double(needed));
  }

  {  // a first picture before the last P6 byte, then the final one
    const json& events = record["events"];
    long first_frame = -1, last_p6 = -1, final_frame = -1;
    for (size_t i = 0; i < events.size(); ++i) {
      const json& e = events[i];
      if (e["type"] == "frame" && first_frame < 0) first_frame = long(i);
      if (e["type"] == "frame" && e["final"] == true) final_frame = long(i);
      if (e["type"] == "received" && e["what"] == "p6") last_p6 = long(i);
    }
    INFO(events.dump());
    REQUIRE(first_frame >= 0);
    REQUIRE(last_p6 >= 0);
    CHECK(first_frame < last_p6);
    CHECK(events[size_t(first_frame)]["final"] == false);
    CHECK(final_frame > last_p6);
  }

  {  // HDR, with code-book rows of both versions: the plane view is btfvq render's image too
    run_browser(server.url() + "/viewer/shop/wood-hdr?scene=plane&light=" + light + "&view=" + view, dir / "hdr");
    const Image render = read_image(dir / "wood-hdr.png"), canvas = read_image(dir / "hdr" / "canvas.png");
    REQUIRE(render.width == 16);
    const auto diff = mean_difference(render, canvas);
    std::printf("plane, wood-hdr: viewer vs btfvq render: mean absolute difference R %.3f G %.3f B %.3f of 255\n", diff[0],
                diff[1], diff[2]);
    for (double d : diff) CHECK(d <= 2.0);
  }

  {  // the sphere is btfvq render --scene sphere's image, pixel for pixel
    btfvq_ok(dir, "render " + db.string() + " --material leather --scene sphere --light 40,135 --tiles 2 --size 512 --out " +
                 (dir / "sphere.png").string());
    run_browser(server.url() + "/viewer/shop/leather?scene=sphere&light=40,135&tiles=2", dir / "sphere");
    const auto diff = mean_difference(read_image(dir / "sphere.png"), read_image(dir / "sphere" / "canvas.png"));
    std::printf("sphere: viewer vs btfvq render --scene sphere: mean absolute difference R %.3f G %.3f B %.3f of 255\n",
                diff[0], diff[1], diff[2]);
    for (double d : diff) CHECK(d <= 2.0);
  }

  {  // the listing names the database and links its material
    const json listing = run_browser(server.url() + "/viewer/", dir / "listing");
    const std::string text = listing["page_text"];
    CHECK(text.find("shop") != std::string::npos);
    CHECK(text.find("leather") != std::string::npos);
    CHECK(text.find("wood-hdr") != std::string::npos);
  }
}
