#pragma once
// A small two-dimensional discrete Fourier transform for the spatial filtering of BTF-CIELab
// (pipeline/metrics/btf_cielab.h), so that the library needs no FFT package. Radix-2 for sizes that
// are powers of two, the plain O(N^2) sum along an axis of any other length. Each 1-D pass runs
// along the slow axis of a row-major array, so every butterfly is a loop over whole rows (one
// twiddle per row pair), which the compiler vectorises; the fast axis is reached by a transpose.
#include <complex>
#include <cstddef>
#include <vector>

namespace btfvq {

class Fft2d {
 public:
  // An image of `height` rows of `width` values.
  Fft2d(size_t width, size_t height);

  size_t width() const { return width_; }
  size_t height() const { return height_; }

  // Forward transform of `image` (height x width, row-major) into `spectrum`, which is stored
  // TRANSPOSED: spectrum[kx * height + ky] is the coefficient of frequency (kx / width, ky / height)
  // cycles per sample, sum_x,y image[y][x] exp(-2 pi i (kx x / width + ky y / height)).
  // `image` is used as scratch and left undefined.
  void forward(std::complex<float>* image, std::complex<float>* spectrum) const;
  // The inverse of forward() WITHOUT the 1 / (width height) factor: from a transposed spectrum back
  // to the image; `spectrum` is used as scratch.
  void inverse(std::complex<float>* spectrum, std::complex<float>* image) const;

 private:
  struct Axis {
    size_t n = 0;
    bool radix2 = false;
    std::vector<std::complex<float>> twiddle;  // radix 2: exp(-2 pi i k / n), k < n/2; else k < n
    std::vector<size_t> reversed;              // radix 2: bit-reversed index
    explicit Axis(size_t n);
  };
  // The transform along the slow axis of an (axis.n x row) array, in place.
  static void along_rows(const Axis& axis, std::complex<float>* data, size_t row, bool inverse);

  size_t width_, height_;
  Axis x_, y_;
};

// out[c * rows + r] = in[r * cols + c].
void transpose(const std::complex<float>* in, std::complex<float>* out, size_t rows, size_t cols);

}  // namespace btfvq
