#include "pipeline/io/image.h"

#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cmath>

#include <btfvq/error.h>
#include "pipeline/util/atomic_file.h"

namespace btfvq {

void write_rgb8_image(const std::string& path, int width, int height, const std::vector<float>& rgb) {
  if (width <= 0 || height <= 0 || rgb.size() != size_t(width) * size_t(height) * 3)
    throw InputError("image for '" + path + "' has the wrong number of values");
  std::vector<uint8_t> pixels(rgb.size());
  for (size_t i = 0; i < rgb.size(); ++i) pixels[i] = uint8_t(std::clamp(std::lround(rgb[i]), 0L, 255L));
  AtomicFile file(path);
  auto out = OIIO::ImageOutput::create(file.temp_path());
  if (!out) throw InputError("cannot write an image named '" + path + "': " + OIIO::geterror());
  OIIO::ImageSpec spec(width, height, 3, OIIO::TypeDesc::UINT8);
  if (!out->open(file.temp_path(), spec) || !out->write_image(OIIO::TypeDesc::UINT8, pixels.data()) || !out->close())
    throw InputError("writing '" + path + "' failed: " + out->geterror());
  file.commit();
}

}  // namespace btfvq
