#include "pipeline/io/image.h"

#include <OpenImageIO/imageio.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include <btfvq/error.h>

namespace btfvq {

void write_rgb8_image(const std::string& path, int width, int height, const std::vector<float>& rgb) {
  if (width <= 0 || height <= 0 || rgb.size() != size_t(width) * size_t(height) * 3)
    throw InputError("image for '" + path + "' has the wrong number of values");
  std::vector<uint8_t> pixels(rgb.size());
  for (size_t i = 0; i < rgb.size(); ++i) pixels[i] = uint8_t(std::clamp(std::lround(rgb[i]), 0L, 255L));
  const std::filesystem::path target(path);
  // Keep the extension on the temporary name: OpenImageIO picks the format from it.
  const std::filesystem::path tmp =
      target.parent_path() / (".tmp-" + std::to_string(::getpid()) + "-" + target.filename().string());
  auto out = OIIO::ImageOutput::create(tmp.string());
  if (!out) throw InputError("cannot write an image named '" + path + "': " + OIIO::geterror());
  OIIO::ImageSpec spec(width, height, 3, OIIO::TypeDesc::UINT8);
  if (!out->open(tmp.string(), spec) || !out->write_image(OIIO::TypeDesc::UINT8, pixels.data()) || !out->close()) {
    const std::string why = out->geterror();
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    throw InputError("writing '" + path + "' failed: " + why);
  }
  std::error_code ec;
  std::filesystem::rename(tmp, target, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    throw InputError("cannot move the finished image to '" + path + "'");
  }
}

}  // namespace btfvq
