#include "support/image_file.h"

#include <doctest/doctest.h>
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

namespace btfvq::test {

namespace {
Image read_all(OIIO::ImageInput& in) {
  const OIIO::ImageSpec& spec = in.spec();
  Image im{spec.width, spec.height, spec.nchannels, {}};
  im.pixels.resize(size_t(im.width) * size_t(im.height) * size_t(im.channels));
  REQUIRE(in.read_image(0, 0, 0, im.channels, OIIO::TypeDesc::UINT8, im.pixels.data()));
  return im;
}
}  // namespace

Image read_image(const std::filesystem::path& path) {
  auto in = OIIO::ImageInput::open(path.string());
  REQUIRE_MESSAGE(in, "cannot read " << path);
  return read_all(*in);
}

Image decode_image(const std::string& bytes, const std::string& name) {
  std::vector<unsigned char> data(bytes.begin(), bytes.end());
  OIIO::Filesystem::IOMemReader proxy(data.data(), data.size());
  auto in = OIIO::ImageInput::open(name, nullptr, &proxy);
  REQUIRE_MESSAGE(in, "cannot decode " << name << " (" << bytes.size() << " bytes)");
  return read_all(*in);
}

}  // namespace btfvq::test
