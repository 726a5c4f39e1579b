#!/usr/bin/env python3
"""Compares the materials of two databases side by side (notebook-style: run whole, or cell by cell
in an editor that knows "# %%" cells, e.g. VS Code or Jupytext).

    /usr/bin/python3 examples/compare_materials.py [DB_A] [DB_B] [--out compare.png]

Defaults: the two real databases of the original compressor in tests/data/btfbase (alu, proposte).
"""
# %% Setup
import argparse
import struct
import sys
import zlib
from pathlib import Path

import numpy as np

import btfvq

ROOT = Path(__file__).resolve().parents[1]
ap = argparse.ArgumentParser(description="compare two databases' materials side by side")
ap.add_argument("db_a", nargs="?", default=str(ROOT / "tests" / "data" / "btfbase" / "alu"))
ap.add_argument("db_b", nargs="?", default=str(ROOT / "tests" / "data" / "btfbase" / "proposte"))
ap.add_argument("--out", default="compare.png")
ap.add_argument("--size", type=int, default=128, help="pixels per tile")
args = ap.parse_args(sys.argv[1:] if "ipykernel" not in sys.modules else [])

# %% Open both databases and list their materials
databases = [btfvq.open(args.db_a), btfvq.open(args.db_b)]
materials = [m for db in databases for m in db.materials]
print(f"{'database':<40} {'material':<16} {'size':>9}  range")
for db in databases:
    for m in db.materials:
        print(f"{db.path:<40} {m.name:<16} {m.width:>4}x{m.height:<4}  {'HDR' if m.hdr else 'LDR'}")

# %% Appearance under a few light/view pairs: one tile per (material, pair), the whole texture once
pairs = [((0, 0), (0, 0)), ((45, 0), (45, 180)), ((60, 90), (30, 270)), ((75, 200), (60, 0))]
s = args.size
ys, xs = np.mgrid[0:s, 0:s]
uv = np.column_stack([(xs.ravel() + 0.5) / s, (ys.ravel() + 0.5) / s])


def tile(m, light, view):
    rgb = m.evaluate(uv, np.asarray(light, float), np.asarray(view, float)).reshape(s, s, 3)
    if m.hdr:  # linear radiance: a simple exposure to the tile's mean, then display gamma
        rgb = 255 * np.clip(rgb / (2 * rgb.mean() + 1e-12), 0, 1) ** (1 / 2.2)
    return np.clip(rgb, 0, 255).astype(np.uint8)


rows = [np.concatenate([tile(m, l, v) for l, v in pairs], axis=1) for m in materials]
grid = np.concatenate(rows, axis=0)
print("tiles (columns, light/view theta,phi):", ", ".join(f"l{l} v{v}" for l, v in pairs))

# %% Albedo against view elevation (paper eq. 6), the mean over a grid of texels
thetas = np.array([0, 15, 30, 45, 60, 75])
grid_uv = np.column_stack([np.repeat(np.arange(8), 8), np.tile(np.arange(8), 8)]) / 8 + 1 / 16
print(f"\n{'mean albedo (luma, sr)':<24}" + "".join(f"{t:>8}" for t in thetas))
for m in materials:
    lum = []
    for t in thetas:
        a = m.albedo(grid_uv, np.array([t, 30.0]))
        lum.append(float(np.mean(a @ np.array([0.299, 0.587, 0.114]))))
    print(f"{m.name:<24}" + "".join(f"{v:8.1f}" for v in lum))

# %% How well each material's importance sampling follows its reflectance: the Monte Carlo
# estimate of the albedo from sample()/pdf() against albedo() at one texel and view.
rng = np.random.default_rng(0)
print(f"\n{'importance sampling':<24}{'albedo()':>10}{'estimate':>10}{'rel. std':>10}")
for m in materials:
    k = 20000
    uvk, view = np.tile([0.3, 0.6], (k, 1)), np.array([30.0, 60.0])
    d, p = m.sample(uvk, view, rng.random((k, 2)))
    w = (m.evaluate(uvk, d, view) @ np.array([0.299, 0.587, 0.114])) * d[:, 2] / p
    exact = float(m.albedo([0.3, 0.6], view) @ np.array([0.299, 0.587, 0.114]))
    print(f"{m.name:<24}{exact:10.1f}{w.mean():10.1f}{w.std() / max(w.mean(), 1e-12):10.2f}")


# %% Write the side-by-side grid as a PNG (zlib + struct only)
def write_png(path, rgb):
    h, w, _ = rgb.shape
    raw = b"".join(b"\0" + rgb[y].tobytes() for y in range(h))
    chunk = lambda tag, data: (struct.pack(">I", len(data)) + tag + data  # noqa: E731
                               + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF))
    Path(path).write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                           + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


write_png(args.out, grid)
print(f"\nwrote {args.out} ({grid.shape[1]}x{grid.shape[0]}: one row per material)")
