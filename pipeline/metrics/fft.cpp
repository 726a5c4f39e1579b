#include "pipeline/metrics/fft.h"

#include <algorithm>
#include <cmath>

namespace btfvq {

namespace {

bool power_of_two(size_t n) { return n > 0 && (n & (n - 1)) == 0; }

// One radix-2 butterfly over whole rows: a' = a + w b, b' = a - w b.
void butterfly(float* a, float* b, size_t row, float wr, float wi) {
  for (size_t j = 0; j < 2 * row; j += 2) {
    const float br = b[j], bi = b[j + 1];
    const float tr = wr * br - wi * bi, ti = wr * bi + wi * br;
    const float ar = a[j], ai = a[j + 1];
    a[j] = ar + tr;
    a[j + 1] = ai + ti;
    b[j] = ar - tr;
    b[j + 1] = ai - ti;
  }
}

void butterfly_unit(float* a, float* b, size_t row) {
  for (size_t j = 0; j < 2 * row; ++j) {
    const float ar = a[j], br = b[j];
    a[j] = ar + br;
    b[j] = ar - br;
  }
}

}  // namespace

Fft2d::Axis::Axis(size_t size) : n(size), radix2(power_of_two(size)) {
  const size_t count = radix2 ? n / 2 : n;
  twiddle.resize(count);
  for (size_t k = 0; k < count; ++k) {
    const double a = -2.0 * 3.14159265358979323846 * double(k) / double(n);
    twiddle[k] = {float(std::cos(a)), float(std::sin(a))};
  }
  if (radix2) {
    reversed.resize(n);
    size_t bits = 0;
    while ((size_t(1) << bits) < n) ++bits;
    for (size_t i = 0; i < n; ++i) {
      size_t r = 0;
      for (size_t b = 0; b < bits; ++b)
        if (i & (size_t(1) << b)) r |= size_t(1) << (bits - 1 - b);
      reversed[i] = r;
    }
  }
}

Fft2d::Fft2d(size_t width, size_t height) : width_(width), height_(height), x_(width), y_(height) {}

void Fft2d::along_rows(const Axis& axis, std::complex<float>* data, size_t row, bool inverse) {
  const size_t n = axis.n;
  if (n <= 1) return;
  if (axis.radix2) {
    for (size_t i = 0; i < n; ++i) {
      const size_t j = axis.reversed[i];
      if (i < j) std::swap_ranges(data + i * row, data + (i + 1) * row, data + j * row);
    }
    for (size_t len = 2; len <= n; len <<= 1) {
      const size_t half = len / 2, step = n / len;
      for (size_t start = 0; start < n; start += len)
        for (size_t k = 0; k < half; ++k) {
          float* a = reinterpret_cast<float*>(data + (start + k) * row);
          float* b = reinterpret_cast<float*>(data + (start + k + half) * row);
          if (k == 0) {
            butterfly_unit(a, b, row);
          } else {
            const std::complex<float> w = axis.twiddle[k * step];
            butterfly(a, b, row, w.real(), inverse ? -w.imag() : w.imag());
          }
        }
    }
    return;
  }
  // Any other length: the plain sum out[k] = sum_m exp(-+2 pi i m k / n) in[m].
  thread_local std::vector<std::complex<float>> scratch;
  scratch.assign(n * row, {0.0f, 0.0f});
  for (size_t k = 0; k < n; ++k) {
    float* out = reinterpret_cast<float*>(scratch.data() + k * row);
    for (size_t m = 0; m < n; ++m) {
      const std::complex<float> w = axis.twiddle[(m * k) % n];
      const float wr = w.real(), wi = inverse ? -w.imag() : w.imag();
      const float* in = reinterpret_cast<const float*>(data + m * row);
      for (size_t j = 0; j < 2 * row; j += 2) {
        out[j] += wr * in[j] - wi * in[j + 1];
        out[j + 1] += wr * in[j + 1] + wi * in[j];
      }
    }
  }
  std::copy(scratch.begin(), scratch.end(), data);
}

void Fft2d::forward(std::complex<float>* image, std::complex<float>* spectrum) const {
  along_rows(y_, image, width_, false);
  transpose(image, spectrum, height_, width_);
  along_rows(x_, spectrum, height_, false);
}

void Fft2d::inverse(std::complex<float>* spectrum, std::complex<float>* image) const {
  along_rows(x_, spectrum, height_, true);
  transpose(spectrum, image, width_, height_);
  along_rows(y_, image, width_, true);
}

void transpose(const std::complex<float>* in, std::complex<float>* out, size_t rows, size_t cols) {
  constexpr size_t kBlock = 32;
  for (size_t r0 = 0; r0 < rows; r0 += kBlock)
    for (size_t c0 = 0; c0 < cols; c0 += kBlock) {
      const size_t r1 = std::min(rows, r0 + kBlock), c1 = std::min(cols, c0 + kBlock);
      for (size_t r = r0; r < r1; ++r)
        for (size_t c = c0; c < c1; ++c) out[c * rows + r] = in[r * cols + c];
    }
}

}  // namespace btfvq
