// `btfvq render`: the decoded image of one material for one (light, view) direction pair, or with
// --scene a preview of the material on a sphere or a plane under a light or a few (--env).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>

#include "client/cli.h"
#include "pipeline/format/database.h"
#include "pipeline/decode/decoder.h"
#include "pipeline/io/image.h"
#include "pipeline/decode/preview.h"
#include "pipeline/decode/reconstruct.h"

namespace btfvq::cli {
namespace {

// The light of a preview: "T,P" in the camera frame (theta may exceed 90: light from behind).
Direction parse_preview_light(const std::string& text) {
  const auto comma = text.find(',');
  try {
    if (comma != std::string::npos) return {std::stod(text.substr(0, comma)), std::stod(text.substr(comma + 1))};
  } catch (const std::exception&) {
  }
  throw InputError("--light: '" + text + "' is not THETA,PHI in degrees");
}

int run_preview(const Args& a, const Database& db, const Material& mat) {
  PreviewOptions o;
  o.scene = parse_preview_scene(a.require("scene"));
  o.size = a.integer("size", 256, 16, 2048);
  if (a.has("env")) o.lights = preview_environment();
  else if (a.has("light")) o.lights = {{parse_preview_light(a.require("light")), 1.0}};
  if (a.has("tiles")) {
    try {
      o.tiles = std::stod(a.require("tiles"));
    } catch (const std::exception&) {
      throw InputError("--tiles: '" + a.require("tiles") + "' is not a number");
    }
  }
  const Decoder decoder(db);
  const size_t index = size_t(&mat - db.materials.data());
  write_rgb8_image(a.require("out"), o.size, o.size, render_preview(decoder, index, o));
  std::cout << "wrote " << a.require("out") << "\n";
  return 0;
}

int run_render(const Args& a) {
  if (a.positional.size() != 1)
    throw InputError("usage: btfvq render DB --material NAME (--light T,P --view T,P | --scene sphere|plane [--light T,P | --env]) --out x.png");
  const Database db = read_database(a.positional[0]);
  const std::string name = a.require("material");
  const Material* mat = db.find(name);
  if (!mat) throw NotFoundError("no material '" + name + "' in " + a.positional[0]);
  if (a.has("scene")) return run_preview(a, db, *mat);
  const Direction light = parse_direction(a.require("light"), "light");
  const Direction view = parse_direction(a.require("view"), "view");
  auto rgb = decode_image(db, name, light, view);
  if (mat->dynamic == Dynamic::HDR)  // a preview of linear radiance: the same tone curve as evaluation
    for (float& v : rgb) v = 255.0f * std::pow(std::max(v, 0.0f), 1.0f / 2.2f);
  write_rgb8_image(a.require("out"), mat->width, mat->height, rgb);
  if (a.has("texel")) {
    // Print one texel's value too, e.g. to compare with known decoded values.
    const auto xy = a.require("texel");
    const auto comma = xy.find(',');
    if (comma == std::string::npos) throw InputError("--texel must be X,Y");
    const int x = std::stoi(xy.substr(0, comma)), y = std::stoi(xy.substr(comma + 1));
    if (x < 0 || y < 0 || x >= mat->width || y >= mat->height) throw InputError("--texel is outside the material");
    const size_t t = (size_t(y) * size_t(mat->width) + size_t(x)) * 3;
    std::printf("texel %d,%d: R %.2f G %.2f B %.2f\n", x, y, rgb[t], rgb[t + 1], rgb[t + 2]);
  }
  std::cout << "wrote " << a.require("out") << "\n";
  return 0;
}

CommandRegistrar reg({"render",
                      "render DB --material NAME --light T,P --view T,P --out x.png [--texel X,Y] | "
                      "render DB --material NAME --scene sphere|plane [--light T,P | --env] [--size N] [--tiles K] --out x.png",
                      "write the decoded image of a material for one light and view direction, or a preview on a sphere/plane",
                      {{"material", "NAME", "the material to render"},
                       {"light", "T,P", "light direction in degrees (with --scene in the camera frame; theta may exceed 90)"},
                       {"view", "T,P", "view direction in degrees, theta in [0, 90]"},
                       {"out", "x.png", "the image to write"},
                       {"texel", "X,Y", "also print the decoded value of this texel"},
                       {"scene", "sphere|plane", "a preview of the material on a sphere or a plane"},
                       {"size", "N", "the preview's width and height in pixels, 16 to 2048 (default 256)"},
                       {"tiles", "K", "how often the texture repeats across the preview (default 2)"}},
                      {{"env", "", "light the preview with a few lights around the scene"}},
                      run_render});

}  // namespace
}  // namespace btfvq::cli
