#!/usr/bin/python3
"""Golden values for tests/test_metrics.cpp from an outside implementation (scikit-image).

Run from the repository root with Debian's python (apt-get install python3-skimage):
    /usr/bin/python3 tests/golden/make_golden.py
Writes the test image pairs as binary PGM files and the reference numbers as TSV files beside this
script. The C++ test reads only those files; it never runs python.
"""
import os
import numpy as np
import scipy
import skimage
from skimage.color import rgb2lab
from skimage.metrics import structural_similarity

HERE = os.path.dirname(os.path.abspath(__file__))
VERSIONS = f"scikit-image {skimage.__version__}, numpy {np.__version__}, scipy {scipy.__version__}"
COMMAND = "/usr/bin/python3 tests/golden/make_golden.py"


def lcg_image(w, h, seed):
    """Integer pseudo-random image: s <- (1103515245 s + 12345) mod 2^31, pixel = (s >> 16) & 255."""
    s, out = seed, np.zeros((h, w), dtype=np.int64)
    for y in range(h):
        for x in range(w):
            s = (1103515245 * s + 12345) % (1 << 31)
            out[y, x] = (s >> 16) & 255
    return out


def grid(w, h):
    return np.meshgrid(np.arange(w), np.arange(h))


def pairs():
    x, y = grid(48, 40)
    a = (3 * x + 5 * y) % 256
    yield "gradient_noise", a, np.clip(a + lcg_image(48, 40, 7) % 41 - 20, 0, 255)
    yield "independent_noise", lcg_image(64, 64, 1), lcg_image(64, 64, 2)
    x, y = grid(37, 29)
    yield "products_odd_size", (x * y) % 256, (x * y + 7 * ((x + y) % 3)) % 256
    a = lcg_image(11, 11, 3)
    yield "single_window", a, 255 - a // 2
    x, y = grid(32, 20)
    a = np.where(((x // 4) + (y // 4)) % 2 == 0, 40, 215)
    yield "inverted_checker", a, 255 - a
    yield "flat", np.full((16, 16), 100), np.full((16, 16), 150)
    x, y = grid(80, 60)
    a = (128 + 100 * np.sin(x / 5.0) * np.cos(y / 7.0)).astype(np.int64)
    yield "blurred_waves", a, (a + np.roll(a, 1, axis=1) + np.roll(a, 1, axis=0)) // 3


def write_pgm(path, img):
    h, w = img.shape
    with open(path, "wb") as f:
        f.write(f"P5\n{w} {h}\n255\n".encode())
        f.write(img.astype(np.uint8).tobytes())


def ssim_golden():
    rows = []
    for name, a, b in pairs():
        assert a.min() >= 0 and a.max() <= 255 and b.min() >= 0 and b.max() <= 255
        write_pgm(os.path.join(HERE, f"{name}_a.pgm"), a)
        write_pgm(os.path.join(HERE, f"{name}_b.pgm"), b)
        m = structural_similarity(a.astype(np.float64), b.astype(np.float64), gaussian_weights=True, sigma=1.5,
                                  use_sample_covariance=False, data_range=255)
        rows.append(f"{name}\t{name}_a.pgm\t{name}_b.pgm\t{a.shape[1]}\t{a.shape[0]}\t{m:.10f}")
    with open(os.path.join(HERE, "ssim_golden.tsv"), "w") as f:
        f.write(f"# {COMMAND} ({VERSIONS}): skimage.metrics.structural_similarity(a, b, gaussian_weights=True, "
                "sigma=1.5, use_sample_covariance=False, data_range=255) on float64 images\n")
        f.write("name\ta\tb\twidth\theight\tmssim\n")
        f.write("\n".join(rows) + "\n")


def lab_golden():
    colours = [(255, 255, 255), (0, 0, 0), (255, 0, 0), (0, 255, 0), (0, 0, 255), (128, 128, 128), (10, 10, 10),
               (1, 2, 3), (200, 150, 100), (30, 200, 220), (250, 240, 10), (90, 20, 160)]
    lab = rgb2lab(np.array([colours], dtype=np.float64) / 255.0)[0]
    with open(os.path.join(HERE, "lab_golden.tsv"), "w") as f:
        f.write(f"# {COMMAND} ({VERSIONS}): skimage.color.rgb2lab(rgb / 255), illuminant D65, observer 2\n")
        f.write("r\tg\tb\tL\ta\tb*\n")
        for c, l in zip(colours, lab):
            f.write(f"{c[0]}\t{c[1]}\t{c[2]}\t{l[0]:.6f}\t{l[1]:.6f}\t{l[2]:.6f}\n")


if __name__ == "__main__":
    ssim_golden()
    lab_golden()
