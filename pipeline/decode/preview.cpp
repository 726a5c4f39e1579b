#include "pipeline/decode/preview.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cmath>

#include <btfvq/error.h>

namespace btfvq {

namespace {

constexpr float kBackground = 40.0f;  // dark grey, so that a dark material is still seen

Vec3 normalized(const Vec3& v) {
  const double l = std::sqrt(v.x * v.x + v.y * v.y + v.z * v.z);
  return {v.x / l, v.y / l, v.z / l};
}
double dot(const Vec3& a, const Vec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
Vec3 cross(const Vec3& a, const Vec3& b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }

// One visible surface point: its shading frame and texture coordinates.
struct SurfacePoint {
  Vec3 n, t, b;
  double u = 0, v = 0;
};

// The surface under pixel (px, py), if any.
bool surface_at(PreviewScene scene, int px, int py, int size, SurfacePoint& s) {
  const double x = (px + 0.5) / size * 2.0 - 1.0, y = 1.0 - (py + 0.5) / size * 2.0;
  if (scene == PreviewScene::Sphere) {
    const double r2 = x * x + y * y;
    if (r2 >= 1.0) return false;
    s.n = {x, y, std::sqrt(1.0 - r2)};
    // Longitude/latitude texture coordinates; the tangent follows increasing longitude.
    s.u = std::atan2(s.n.x, s.n.z) / (2.0 * kPi) + 0.5;
    s.v = std::acos(std::clamp(s.n.y, -1.0, 1.0)) / kPi;
    const double h = std::sqrt(s.n.x * s.n.x + s.n.z * s.n.z);
    s.t = h > 1e-9 ? Vec3{s.n.z / h, 0, -s.n.x / h} : Vec3{1, 0, 0};
  } else {
    // A plane tilted 50 degrees back from the camera, filling the frame.
    constexpr double tilt = 50.0 * kDeg;
    s.n = {0, std::sin(tilt), std::cos(tilt)};
    s.t = {1, 0, 0};
    s.u = 0.5 * (x + 1.0);
    s.v = 0.5 * (1.0 - y) / std::cos(tilt);
  }
  s.b = cross(s.n, s.t);
  return true;
}

Direction local_direction(const SurfacePoint& s, const Vec3& w) { return to_direction({dot(w, s.t), dot(w, s.b), dot(w, s.n)}); }

void validate(const PreviewOptions& o) {
  if (o.size < 16 || o.size > 2048) throw InputError("preview size must be within 16..2048 pixels, got " + std::to_string(o.size));
  if (o.lights.empty() || o.lights.size() > 64) throw InputError("a preview needs 1..64 lights");
  for (const PreviewLight& l : o.lights)
    if (!(l.direction.theta >= 0 && l.direction.theta <= 180) || !std::isfinite(l.direction.phi) ||
        !(l.intensity >= 0) || !std::isfinite(l.intensity))
      throw InputError("preview light: theta must be within 0..180 degrees and intensity a non-negative number");
  if (!(o.tiles > 0 && o.tiles <= 1024)) throw InputError("preview tiles must be within (0, 1024]");
  if (!(o.exposure > 0) || !std::isfinite(o.exposure)) throw InputError("preview exposure must be positive");
}

}  // namespace

PreviewScene parse_preview_scene(const std::string& name) {
  if (name == "sphere") return PreviewScene::Sphere;
  if (name == "plane") return PreviewScene::Plane;
  throw InputError("scene: '" + name + "' is not one of sphere, plane");
}

std::vector<PreviewLight> preview_environment() {
  return {{{40, 135}, 0.55}, {{55, 20}, 0.25}, {{70, 250}, 0.2}, {{25, 300}, 0.15}, {{80, 90}, 0.2}, {{10, 0}, 0.15}};
}

std::vector<float> render_preview(const Decoder& decoder, size_t material, const PreviewOptions& o) {
  validate(o);
  const Database& db = decoder.database();
  if (material >= db.materials.size())
    throw NotFoundError("material index " + std::to_string(material) + " is past the end of the database");
  const Material& mat = db.materials[material];
  const bool hdr = mat.dynamic == Dynamic::HDR;
  const int n = o.size;
  std::vector<Vec3> lights;
  for (const PreviewLight& l : o.lights) lights.push_back(normalized(to_vector(l.direction)));
  const Vec3 eye{0, 0, 1};

  std::vector<DecodeQuery> queries;
  std::vector<size_t> pixel_of;  // query -> pixel
  std::vector<uint32_t> light_of;
  for (int py = 0; py < n; ++py)
    for (int px = 0; px < n; ++px) {
      SurfacePoint s;
      if (!surface_at(o.scene, px, py, n, s)) continue;
      const Direction view = local_direction(s, eye);
      const double cu = s.u * o.tiles, cv = s.v * o.tiles;
      const int32_t tx = int32_t(std::floor((cu - std::floor(cu)) * mat.width));
      const int32_t ty = int32_t(std::floor((cv - std::floor(cv)) * mat.height));
      for (size_t l = 0; l < lights.size(); ++l) {
        if (dot(lights[l], s.n) <= 0) continue;  // the decoder would return zero anyway
        queries.push_back({uint32_t(material), tx, ty, local_direction(s, lights[l]), view});
        pixel_of.push_back(size_t(py) * size_t(n) + size_t(px));
        light_of.push_back(uint32_t(l));
      }
    }
  const std::vector<Rgb> values = decoder.decode(queries);

  // Sum the lights in linear radiance, then encode for display.
  std::vector<double> linear(size_t(n) * size_t(n) * 3, 0.0);
  std::vector<uint8_t> covered(size_t(n) * size_t(n), 0);
  for (int py = 0; py < n; ++py)
    for (int px = 0; px < n; ++px) {
      SurfacePoint s;
      covered[size_t(py) * size_t(n) + size_t(px)] = surface_at(o.scene, px, py, n, s) ? 1 : 0;
    }
  auto to_linear = [hdr](float v) { return hdr ? double(v) : std::pow(std::max(double(v), 0.0) / 255.0, 2.2); };
  for (size_t q = 0; q < values.size(); ++q) {
    const double k = o.lights[light_of[q]].intensity * o.exposure;
    double* p = &linear[pixel_of[q] * 3];
    p[0] += k * to_linear(values[q].r);
    p[1] += k * to_linear(values[q].g);
    p[2] += k * to_linear(values[q].b);
  }
  std::vector<float> rgb(linear.size(), kBackground);
  for (size_t i = 0; i < covered.size(); ++i)
    if (covered[i])
      for (int c = 0; c < 3; ++c) rgb[i * 3 + size_t(c)] = float(255.0 * std::pow(std::max(linear[i * 3 + size_t(c)], 0.0), 1.0 / 2.2));
  return rgb;
}

std::vector<uint8_t> render_preview_png(const Decoder& decoder, size_t material, const PreviewOptions& options) {
  const std::vector<float> rgb = render_preview(decoder, material, options);
  std::vector<uint8_t> pixels(rgb.size());
  for (size_t i = 0; i < rgb.size(); ++i) pixels[i] = uint8_t(std::clamp(std::lround(rgb[i]), 0L, 255L));
  std::vector<unsigned char> png;
  OIIO::Filesystem::IOVecOutput proxy(png);
  auto out = OIIO::ImageOutput::create("preview.png", &proxy);
  if (!out) throw Error("image", "PNG output is not available: " + OIIO::geterror());
  OIIO::ImageSpec spec(options.size, options.size, 3, OIIO::TypeDesc::UINT8);
  if (!out->open("preview.png", spec) || !out->write_image(OIIO::TypeDesc::UINT8, pixels.data()) || !out->close())
    throw Error("image", "encoding the preview as PNG failed: " + out->geterror());
  return {png.begin(), png.end()};
}

}  // namespace btfvq
