#pragma once
// Writing single images (previews, renders). The file appears atomically: written under a temporary
// name and renamed when complete.
#include <string>
#include <vector>

namespace btfvq {

// Writes 8-bit RGB from floats in 0..255 (rounded and clamped); the format follows the extension
// (.png, .jpg, .tif, ... as OpenImageIO knows them). Throws InputError naming the path on failure.
void write_rgb8_image(const std::string& path, int width, int height, const std::vector<float>& rgb);

}  // namespace btfvq
