#pragma once
// Evaluation metrics (DESIGN.md step 10): how far a reconstructed BTF is from the measured one.
// Each metric follows an outside reference exactly; docs/metrics.md gives the definitions.
//  - SSIM / MSSIM: Wang, Bovik, Sheikh, Simoncelli 2004 (the reference ssim_index.m).
//  - PSNR over 8-bit values.
//  - CIEDE2000: Sharma, Wu, Dalal 2005, on CIELAB from gamma-encoded sRGB under D65.
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "pipeline/btf.h"
#include <btfvq/colour.h>

namespace btfvq {

// A single-channel image, row-major, values on the 0..255 scale.
struct GrayImage {
  int width = 0, height = 0;
  std::vector<float> pixels;  // width * height

  GrayImage() = default;
  GrayImage(int w, int h) : width(w), height(h), pixels(size_t(w) * size_t(h), 0.0f) {}
  float& at(int x, int y) { return pixels[size_t(y) * size_t(width) + size_t(x)]; }
  float at(int x, int y) const { return pixels[size_t(y) * size_t(width) + size_t(x)]; }
};

// Wang et al. 2004 constants: 11x11 Gaussian window of sigma 1.5 (weights normalised to sum 1),
// K1 = 0.01, K2 = 0.03, dynamic range L = 255.
struct SsimParameters {
  int window = 11;
  double sigma = 1.5;
  double k1 = 0.01, k2 = 0.03;
  double dynamic_range = 255.0;
};

// The SSIM map over the 'valid' region: one value per window lying fully inside the image, so
// (W - 10) x (H - 10) values for the default window. An image narrower or lower than the window
// uses a window as wide (high) as the image in that axis (Gaussian, same sigma, normalised).
// Throws InputError if the sizes differ or an image is empty.
GrayImage ssim_map(const GrayImage& a, const GrayImage& b, const SsimParameters& p = {});
// Mean of ssim_map (MSSIM).
double mssim(const GrayImage& a, const GrayImage& b, const SsimParameters& p = {});

// PSNR = 10 log10(255^2 / MSE), MSE over all values given (e.g. every channel of every pixel).
// Identical inputs (MSE = 0) give +infinity, explicitly. Throws InputError on size mismatch or empty.
double psnr_from_mse(double mse);
double psnr(std::span<const uint8_t> a, std::span<const uint8_t> b);

// CIELAB (L*, a*, b*) relative to the D65 white.
struct CieLab {
  double l = 0, a = 0, b = 0;
};
// Gamma-encoded sRGB on 0..255 (IEC 61966-2-1 transfer curve, Rec. 709 primaries, D65 white)
// to CIELAB; inputs outside 0..255 are clamped.
CieLab srgb_to_lab(const Rgb& srgb8);
// The two halves of srgb_to_lab, for metrics that work in between (BTF-CIELab):
// one clamped 0..255 gamma-encoded channel to linear 0..1 (IEC 61966-2-1), and CIE XYZ (Y of the
// white = 1) to CIELAB relative to D65. srgb_to_lab(c) is xyz_to_lab(kSrgbToXyz * linear(c)).
double srgb8_to_linear(float v);
CieLab xyz_to_lab(double x, double y, double z);
// Linear Rec. 709 RGB to XYZ, D65 (Lindbloom's matrix; rows sum to the white point), row-major.
inline constexpr double kSrgbToXyz[9] = {0.4124564, 0.3575761, 0.1804375, 0.2126729, 0.7151522,
                                         0.0721750, 0.0193339, 0.1191920, 0.9503041};
// CIEDE2000 colour difference with kL = kC = kH = 1 (Sharma, Wu, Dalal 2005).
double ciede2000(const CieLab& x, const CieLab& y);

// Metrics of a reconstructed sample against the measured one, over every (view, light) image.
struct EvaluationReport {
  double mssim_y = 0;          // mean over images of MSSIM on BT.601 luma (0.299 R + 0.587 G + 0.114 B)
  double mssim_cb = 0;         // mean over images of MSSIM on BT.601 studio-swing Cb
  double mssim_cr = 0;         // ... and Cr
  double psnr = 0;             // over all values of all images; +inf if identical
  double ciede2000_mean = 0;   // over every texel of every image
  double ciede2000_p95 = 0;    // nearest-rank 95th percentile, resolved to kCiede2000Resolution
  size_t images = 0;           // number of (view, light) images compared
};
// Width of the histogram bins the 95th percentile is read from (the centre of the bin is reported).
constexpr double kCiede2000Resolution = 1.0 / 4096.0;

// The 8-bit display value of a sample value: LDR values as they are; HDR linear radiance is
// tone-mapped clamp(255 * max(v, 0)^(1/2.2), 0, 255) (kept as a real number, not rounded; NaN -> 0).
float display_value(float v, Dynamic dynamic);

// Compares two samples of identical geometry (size, views, lights, dynamic range; else InputError).
// Runs on `threads` worker threads; the result does not depend on the thread count.
EvaluationReport evaluate(const MeasuredSample& reference, const MeasuredSample& test, int threads = 2);

}  // namespace btfvq
