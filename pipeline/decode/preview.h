#pragma once
// Preview renders of a material (`btfvq render --scene`, the server's preview.png): the BTF on a
// sphere or on a tilted plane, seen by an orthographic camera, lit by directional lights (a point
// light far away) or by a small environment made of a few of them. Every (pixel, light) pair is one
// query of the batch decode (Decoder::decode, on the compute device).
//
// Frames: the camera looks down -z; image x to the right, y up. A light direction is (theta, phi)
// in degrees in that frame: theta from the camera axis, phi the azimuth from the image's +x axis
// towards +y (so 45,135 is up-left, in front). The texture is wrapped `tiles` times around the
// sphere (longitude, latitude) or across the plane.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "pipeline/decode/decoder.h"
#include <btfvq/directions.h>

namespace btfvq {

enum class PreviewScene { Sphere, Plane };

// "sphere" or "plane"; InputError naming the value otherwise.
PreviewScene parse_preview_scene(const std::string& name);

struct PreviewLight {
  Direction direction;   // camera frame, degrees
  double intensity = 1;  // 1 reproduces the decoded value of a surface lit by this light alone
};

struct PreviewOptions {
  PreviewScene scene = PreviewScene::Sphere;
  int size = 256;  // square image, pixels (16..2048)
  std::vector<PreviewLight> lights{{{45, 135}, 1.0}};
  double tiles = 2;  // texture repeats
  double exposure = 1;
};

// A few lights around the camera side of the scene (key, fill, rim, top, low ones): an environment.
std::vector<PreviewLight> preview_environment();

// RGB 0..255 (gamma-encoded, not clamped; size x size x 3, row-major from the top row) of material
// `material` of the decoder's database. Decoded LDR values are linearised (gamma 2.2) before the
// lights are summed, so one light of intensity 1 gives the decoded value itself. Throws InputError
// for bad options, NotFoundError for a material index past the end.
std::vector<float> render_preview(const Decoder& decoder, size_t material, const PreviewOptions& options);

// The same as PNG file bytes (8-bit RGB).
std::vector<uint8_t> render_preview_png(const Decoder& decoder, size_t material, const PreviewOptions& options);

}  // namespace btfvq
