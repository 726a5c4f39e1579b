// `btfvq render`: the decoded image of one material for one (light, view) direction pair.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>

#include "client/cli.h"
#include "pipeline/database.h"
#include "pipeline/image.h"
#include "pipeline/reconstruct.h"

namespace btfvq::cli {
namespace {

int run_render(const Args& a) {
  if (a.positional.size() != 1)
    throw InputError("usage: btfvq render DB --material NAME --light T,P --view T,P --out x.png");
  const Database db = read_database(a.positional[0]);
  const std::string name = a.require("material");
  const Material* mat = db.find(name);
  if (!mat) throw NotFoundError("no material '" + name + "' in " + a.positional[0]);
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

CommandRegistrar reg({"render", "render DB --material NAME --light T,P --view T,P --out x.png [--texel X,Y]",
                      "write the decoded image of a material for one light and view direction",
                      {"material", "light", "view", "out", "texel"}, {}, run_render});

}  // namespace
}  // namespace btfvq::cli
