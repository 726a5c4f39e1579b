#include <btfvq/colour.h>

#include <algorithm>
#include <cmath>

namespace btfvq {

YCbCr rgb_to_ycbcr(const Rgb& c) {
  return {16.0f + (65.481f * c.r + 128.553f * c.g + 24.966f * c.b) / 255.0f,
          128.0f + (-37.797f * c.r - 74.203f * c.g + 112.0f * c.b) / 255.0f,
          128.0f + (112.0f * c.r - 93.786f * c.g - 18.214f * c.b) / 255.0f};
}

Rgb ycbcr_to_rgb(const YCbCr& v) {
  const float r = 1.1643828f * v.y + 1.5960273f * v.cr - 222.921f;
  const float g = 1.1643828f * v.y - 0.39176172f * v.cb - 0.81296875f * v.cr + 135.576f;
  const float b = 1.1643828f * v.y + 2.0172344f * v.cb - 276.836f;
  return {std::max(r, 0.0f), std::max(g, 0.0f), std::max(b, 0.0f)};
}

namespace {
// D65 white point chromaticity, used for black where (u', v') is undefined.
constexpr float kWhiteU = 0.197839f, kWhiteV = 0.468342f;
constexpr float kMinY = 1e-12f;
}  // namespace

LogLuv rgb_to_logluv(const Rgb& c) {
  const float X = 0.4124564f * c.r + 0.3575761f * c.g + 0.1804375f * c.b;
  const float Y = 0.2126729f * c.r + 0.7151522f * c.g + 0.0721750f * c.b;
  const float Z = 0.0193339f * c.r + 0.1191920f * c.g + 0.9503041f * c.b;
  const float d = X + 15.0f * Y + 3.0f * Z;
  if (Y <= kMinY || d <= 0) return {std::log2(kMinY), kWhiteU, kWhiteV};
  return {std::log2(Y), 4.0f * X / d, 9.0f * Y / d};
}

Rgb logluv_to_rgb(const LogLuv& luv) {
  const float Y = std::exp2(luv.log2_y);
  const float v = std::max(luv.v, 1e-6f);
  const float X = Y * 9.0f * luv.u / (4.0f * v);
  const float Z = Y * (12.0f - 3.0f * luv.u - 20.0f * v) / (4.0f * v);
  return {3.2404542f * X - 1.5371385f * Y - 0.4985314f * Z, -0.9692660f * X + 1.8760108f * Y + 0.0415560f * Z,
          0.0556434f * X - 0.2040259f * Y + 1.0572252f * Z};
}

Lab3 to_coding_space(const Rgb& rgb, bool hdr) {
  if (!hdr) {
    const YCbCr v = rgb_to_ycbcr(rgb);
    return {v.y, v.cb, v.cr};
  }
  const LogLuv l = rgb_to_logluv(rgb);
  return {std::exp2(l.log2_y), l.u * 255.0f, l.v * 255.0f};
}

Rgb from_coding_space(const Lab3& lab, bool hdr) {
  if (!hdr) return ycbcr_to_rgb({lab.l, lab.a, lab.b});
  const float y = std::max(lab.l, 0.0f);
  Rgb c = logluv_to_rgb({std::log2(std::max(y, kMinY)), lab.a / 255.0f, lab.b / 255.0f});
  if (y <= kMinY) return {0, 0, 0};
  return c;
}

}  // namespace btfvq
