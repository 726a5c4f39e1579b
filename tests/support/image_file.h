#pragma once
// An 8-bit image as the tests check it: the PNGs that `btfvq render`, the server's preview route and
// the viewer's canvas dumps write, read back with OpenImageIO (REQUIREs that it reads).
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace btfvq::test {

struct Image {
  int width = 0, height = 0, channels = 0;
  std::vector<uint8_t> pixels;  // row-major, channels interleaved
  int at(int x, int y, int c) const { return pixels[(size_t(y) * size_t(width) + size_t(x)) * size_t(channels) + size_t(c)]; }
};

Image read_image(const std::filesystem::path& path);
// An image file's bytes held in memory (an HTTP body); `name` gives OpenImageIO the format.
Image decode_image(const std::string& bytes, const std::string& name = "image.png");

}  // namespace btfvq::test
