#!/usr/bin/env python3
"""Renders a BTF material on a sphere under an environment light, with NumPy only.

Every pixel's light integral is estimated by multiple importance sampling of two strategies, each
over whole arrays at once (no per-pixel Python loop):
  - the material's own importance sampling: Material.sample() gives light directions and their pdf;
  - cosine-weighted hemisphere directions, whose density under the first strategy is Material.pdf();
combined with the balance heuristic. The PNG is written with zlib + struct from the standard library.

    /usr/bin/python3 examples/render_sphere.py [--db tests/data/btfbase/proposte] [--out sphere.png]

(PYTHONPATH=build/python for the module of a build tree; `make install` puts it into Debian's Python.)
"""
import argparse
import struct
import time
import zlib
from pathlib import Path

import numpy as np

import btfvq

ROOT = Path(__file__).resolve().parents[1]


def environment(d):
    """Radiance of the environment for world directions d (..., 3): a sky, a ground and a sun."""
    up = d[..., 1:2]
    sky = np.where(up > 0, np.array([0.35, 0.5, 0.8]) * (0.4 + 0.6 * up), np.array([0.25, 0.2, 0.15]) * 0.6)
    sun_dir = np.array([0.6, 0.65, 0.45]) / np.linalg.norm([0.6, 0.65, 0.45])
    cos_sun = d @ sun_dir
    sun = np.exp((cos_sun - 1) / 0.01)[..., None] * np.array([6.0, 5.4, 4.5])  # a lobe of about 8 degrees
    return sky + sun


def write_png(path, rgb):
    """8-bit RGB PNG: one IHDR, one zlib IDAT of filter-0 rows, IEND."""
    h, w, _ = rgb.shape
    raw = b"".join(b"\0" + rgb[y].tobytes() for y in range(h))

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    Path(path).write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                           + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def render(material, size=256, spp=16, tiles=2.0, seed=1):
    # Orthographic camera looking down -z at a unit sphere: normals, and a tangent frame following
    # the sphere's longitude (tangent) and latitude, in which the BTF's directions live.
    ys, xs = np.mgrid[0:size, 0:size]
    x = (xs + 0.5) / size * 2 - 1
    y = 1 - (ys + 0.5) / size * 2
    inside = x * x + y * y < 1
    n = np.stack([x[inside], y[inside], np.sqrt(1 - x[inside] ** 2 - y[inside] ** 2)], axis=1)
    phi = np.arctan2(n[:, 0], n[:, 2])
    theta = np.arccos(np.clip(n[:, 1], -1, 1))
    t = np.stack([np.cos(phi), np.zeros_like(phi), -np.sin(phi)], axis=1)
    b = np.cross(n, t)
    uv = np.stack([phi / (2 * np.pi) * tiles % 1.0, theta / np.pi * tiles / 2 % 1.0], axis=1)
    to_camera = np.array([0.0, 0.0, 1.0])
    view = np.stack([t @ to_camera, b @ to_camera, n @ to_camera], axis=1)
    view[:, 2] = np.maximum(view[:, 2], 1e-4)  # grazing silhouette pixels stay above the horizon

    half = max(spp // 2, 1)
    rng = np.random.default_rng(seed)
    P = len(n)
    rep = lambda a: np.repeat(a, half, axis=0)  # noqa: E731  (pixel-major: half samples per pixel)
    uv_s, view_s, t_s, b_s, n_s = rep(uv), rep(view), rep(t), rep(b), rep(n)

    def to_world(local):
        return local[:, :1] * t_s + local[:, 1:2] * b_s + local[:, 2:3] * n_s

    def linear(values):
        # LDR BTFs are gamma-encoded 0..255 (the decoder's output); HDR ones are already linear.
        return values if material.hdr else (np.maximum(values, 0) / 255.0) ** 2.2

    # Strategy 1: the material's importance sampling.
    l1, p1 = material.sample(uv_s, view_s, rng.random((P * half, 2)))
    f1 = linear(material.evaluate(uv_s, l1, view_s))
    q1 = l1[:, 2] / np.pi  # the density strategy 2 would have drawn these with
    w1 = p1 / (p1 + q1)
    c1 = f1 * l1[:, 2:3] * environment(to_world(l1)) * (w1 / p1)[:, None]

    # Strategy 2: cosine-weighted hemisphere directions; their density under strategy 1 from pdf().
    xi = rng.random((P * half, 2))
    r, a = np.sqrt(xi[:, 0]), 2 * np.pi * xi[:, 1]
    l2 = np.stack([r * np.cos(a), r * np.sin(a), np.sqrt(np.maximum(1 - xi[:, 0], 1e-12))], axis=1)
    q2 = l2[:, 2] / np.pi
    p2 = material.pdf(uv_s, l2, view_s)
    f2 = linear(material.evaluate(uv_s, l2, view_s))
    w2 = q2 / (p2 + q2)
    c2 = f2 * l2[:, 2:3] * environment(to_world(l2)) * (w2 / q2)[:, None]

    # Each strategy's estimator averages its own samples; the MIS weights make their sum unbiased.
    radiance = (c1.reshape(P, half, 3).mean(axis=1) + c2.reshape(P, half, 3).mean(axis=1)) / np.pi
    image = np.full((size, size, 3), 0.08)
    image[inside] = radiance
    srgb = np.clip(image / (1 + image), 0, 1) ** (1 / 2.2)  # Reinhard, then display gamma
    return (srgb * 255 + 0.5).astype(np.uint8)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--db", default=str(ROOT / "tests" / "data" / "btfbase" / "proposte"))
    ap.add_argument("--material", default=None, help="default: the database's first material")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--spp", type=int, default=16, help="samples per pixel, half per strategy")
    ap.add_argument("--tiles", type=float, default=2.0, help="material repeats around the sphere")
    ap.add_argument("--out", default="sphere.png")
    args = ap.parse_args()
    start = time.perf_counter()
    db = btfvq.open(args.db)
    material = db[args.material] if args.material else db.materials[0]
    opened = time.perf_counter()
    image = render(material, args.size, args.spp, args.tiles)
    write_png(args.out, image)
    done = time.perf_counter()
    print(f"{args.out}: {material.name} {args.size}x{args.size}, {args.spp} spp, rendered in {done - opened:.2f} s "
          f"(opening the database {opened - start:.2f} s; {btfvq.device()})")


if __name__ == "__main__":
    main()
