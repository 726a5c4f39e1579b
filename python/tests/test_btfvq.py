"""The Python module against the C++ API (issue 20).

Expected values never come from the module: they come from bin/btfvq_reference (python/tools), a
C++ program that answers the same queries through BtfMaterial (one query at a time) and
Decoder::decode (the C++ batch path), or from files this test writes itself.
Run by ctest (python_btfvq) with PYTHONPATH at the built module and BTFVQ_BIN_DIR, BTFVQ_SOURCE_DIR.
"""
import os
import struct
import subprocess
import sys
import time
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

import btfvq

SOURCE = Path(os.environ.get("BTFVQ_SOURCE_DIR", Path(__file__).resolve().parents[2]))
BIN = Path(os.environ.get("BTFVQ_BIN_DIR", SOURCE / "build" / "bin"))
BTFBASE = SOURCE / "tests" / "data" / "btfbase"
REFERENCE = BIN / "btfvq_reference"
N = 10_000
ALBEDO_N = 100


# --------------------------------------------------------------------------------------------------
# Queries and the C++ answers to them.

def random_queries(seed, n=N):
    rng = np.random.default_rng(seed)
    uv = rng.random((n, 2))

    def vectors():
        v = rng.normal(size=(n, 3))
        v[:, 2] = np.abs(v[:, 2])
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        return v * rng.uniform(0.5, 2.0, (n, 1))  # not normalised: the API takes any length

    light, view = vectors(), vectors()
    light[: n // 50, 2] *= -1  # 2 % of the lights below the horizon
    light_ang = np.column_stack([rng.uniform(0, 89.9, n), rng.uniform(0, 360, n)])
    view_ang = np.column_stack([rng.uniform(0, 89.9, n), rng.uniform(0, 360, n)])
    xi = rng.random((n, 2))
    return dict(uv=uv, light=light, view=view, light_ang=light_ang, view_ang=view_ang, xi=xi)


def write_queries(q, path):
    rows = np.column_stack([q["uv"], q["light"], q["view"], q["light_ang"], q["view_ang"], q["xi"]])
    assert rows.shape[1] == 14
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", rows.shape[0]))
        f.write(np.ascontiguousarray(rows, dtype="<f8").tobytes())


def cpp_values(db_path, material, q, tmp, albedo_n=ALBEDO_N, env=None):
    qfile, out = tmp / f"{material}.queries", tmp / f"{material}.values"
    write_queries(q, qfile)
    subprocess.run([str(REFERENCE), "values", str(db_path), material, str(qfile), str(out), str(albedo_n)],
                   check=True, env=env, capture_output=True)
    raw = open(out, "rb").read()
    n, pos, blocks = len(q["uv"]), 0, {}
    for name, dtype, count in [("eval_vec", "<f4", 3 * n), ("eval_ang", "<f4", 3 * n), ("batch_vec", "<f4", 3 * n),
                               ("batch_ang", "<f4", 3 * n), ("sample_dir", "<f8", 3 * n), ("sample_pdf", "<f8", n),
                               ("pdf_vec", "<f8", n), ("pdf_ang", "<f8", n), ("albedo", "<f4", 3 * albedo_n)]:
        a = np.frombuffer(raw, dtype=dtype, count=count, offset=pos)
        pos += a.nbytes
        blocks[name] = a.reshape(-1, 3) if count != n else a
    assert pos == len(raw)
    return blocks


MATERIALS = {"alu": BTFBASE / "alu", "proposte": BTFBASE / "proposte"}


@pytest.fixture(scope="module", params=sorted(MATERIALS))
def case(request, tmp_path_factory):
    name = request.param
    db = btfvq.open(MATERIALS[name])
    q = random_queries(seed=20 + len(name))
    ref = cpp_values(MATERIALS[name], name, q, tmp_path_factory.mktemp(name))
    return db, db[name], q, ref


def uses_opencl():
    return "reference" not in btfvq.device().lower()


# --------------------------------------------------------------------------------------------------
# Opening, metadata.

def test_open_lists_materials_with_metadata():
    alu = btfvq.open(str(BTFBASE / "alu"))
    assert alu.names == ["alu"] and len(alu) == 1 and "alu" in alu and "wood" not in alu
    m = alu.materials[0]
    # tests/data/btfbase/alu/alu_materialInfo.txt: "... 0 0 64 64"; proposte's says 256 256.
    assert (m.name, m.width, m.height, m.hdr, m.index) == ("alu", 64, 64, False, 0)
    p = btfvq.open(BTFBASE / "proposte")["proposte"]  # os.PathLike works too
    assert (p.width, p.height, p.hdr) == (256, 256, False)
    assert alu[0].name == alu["alu"].name == alu.material(-1).name == "alu"


# --------------------------------------------------------------------------------------------------
# Evaluation equals the C++ API's on 10,000 random queries, both real databases.

def test_evaluate_equals_cpp_batch(case):
    db, m, q, ref = case
    vec = m.evaluate(q["uv"], q["light"], q["view"])
    ang = m.evaluate(q["uv"], q["light_ang"], q["view_ang"])
    assert vec.shape == (N, 3) and vec.dtype == np.float32 and ang.shape == (N, 3) and ang.dtype == np.float32
    # The same batch path (Decoder::decode on the same device) as a C++ batch caller.
    np.testing.assert_allclose(vec, ref["batch_vec"], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(ang, ref["batch_ang"], rtol=1e-6, atol=1e-6)
    # And the per-query BtfMaterial::evaluate: identical on the C++ path; the OpenCL kernel computes
    # in float (docs/python.md, pipeline/decode/decoder.h: relative difference below 1e-3).
    tol = dict(rtol=1e-3, atol=1e-3) if uses_opencl() else dict(rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(vec, ref["eval_vec"], **tol)
    np.testing.assert_allclose(ang, ref["eval_ang"], **tol)
    # Real values: lights below the horizon give zero, the rest mostly do not.
    assert np.all(vec[: N // 50] == 0)
    assert np.mean(vec[N // 50:, 1] > 0) > 0.9


def test_evaluate_equals_per_query_cpp_api_on_the_cpu_path(tmp_path):
    """BTFVQ_DEVICE=cpu-reference: the module evaluates per query (over every core) exactly as BtfMaterial does."""
    for name, path in MATERIALS.items():
        q = random_queries(seed=99 + len(name))
        ref = cpp_values(path, name, q, tmp_path, albedo_n=0)
        np.savez(tmp_path / "q.npz", **q)
        script = (
            "import numpy as np, btfvq, sys\n"
            "q = np.load(sys.argv[1]); m = btfvq.open(sys.argv[2])[sys.argv[3]]\n"
            "assert 'reference' in btfvq.device().lower(), btfvq.device()\n"
            "np.save(sys.argv[4], m.evaluate(q['uv'], q['light'], q['view']))\n"
            "np.save(sys.argv[5], m.evaluate(q['uv'], q['light_ang'], q['view_ang']))\n")
        env = dict(os.environ, BTFVQ_DEVICE="cpu-reference")
        subprocess.run([sys.executable, "-c", script, str(tmp_path / "q.npz"), str(path), name,
                        str(tmp_path / "v.npy"), str(tmp_path / "a.npy")], check=True, env=env)
        np.testing.assert_allclose(np.load(tmp_path / "v.npy"), ref["eval_vec"], rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(np.load(tmp_path / "a.npy"), ref["eval_ang"], rtol=1e-6, atol=1e-6)


def test_sample_and_pdf_agree_with_cpp(case):
    db, m, q, ref = case
    dirs, pdf = m.sample(q["uv"], q["view"], q["xi"])
    assert dirs.shape == (N, 3) and dirs.dtype == np.float64 and pdf.shape == (N,) and pdf.dtype == np.float64
    np.testing.assert_allclose(dirs, ref["sample_dir"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(pdf, ref["sample_pdf"], rtol=1e-9)
    p = m.pdf(q["uv"], q["light"], q["view"])
    assert p.shape == (N,) and p.dtype == np.float64
    np.testing.assert_allclose(p, ref["pdf_vec"], rtol=1e-9, atol=1e-300)
    np.testing.assert_allclose(m.pdf(q["uv"], q["light_ang"], q["view_ang"]), ref["pdf_ang"], rtol=1e-9, atol=1e-300)
    # Sampled directions are unit vectors on the upper hemisphere, below-horizon lights have density 0.
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1, atol=1e-9)
    assert np.all(dirs[:, 2] >= 0) and np.all(pdf > 0)
    assert np.all(p[: N // 50] == 0)


def test_albedo_agrees_with_cpp(case):
    db, m, q, ref = case
    a = m.albedo(q["uv"][:ALBEDO_N], q["view"][:ALBEDO_N])
    assert a.shape == (ALBEDO_N, 3) and a.dtype == np.float32
    np.testing.assert_allclose(a, ref["albedo"], rtol=1e-6, atol=1e-6)
    assert np.all(a > 0)


def test_broadcast_and_input_dtypes(case):
    db, m, q, ref = case
    uv = q["uv"][:50]
    view = np.array([0.2, -0.1, 0.9])
    one = m.evaluate(uv, q["light"][:50], view)  # (3,) is one view for every query
    many = m.evaluate(uv, q["light"][:50], np.tile(view, (50, 1)))
    np.testing.assert_array_equal(one, many)
    uv32 = uv.astype(np.float32)  # any real dtype, converted to float64
    np.testing.assert_array_equal(m.evaluate(uv32, q["light"][:50], view),
                                  m.evaluate(uv32.astype(np.float64), q["light"][:50], view))
    single = m.evaluate([0.25, 0.5], [0, 0, 1], [45, 90])  # every input one value: a (3,) result
    assert single.shape == (3,) and single.dtype == np.float32
    d, p = m.sample([0.25, 0.5], [0, 0, 1], [0.5, 0.5])
    assert d.shape == (3,) and p.shape == ()
    assert m.evaluate(np.zeros((0, 2)), np.zeros((0, 3)) + 1, np.zeros((0, 3)) + 1).shape == (0, 3)
    assert m.evaluate(np.array([[0, 0]]), np.array([[0, 0, 1]]), np.array([[0, 0, 1]], dtype=np.int32)).shape == (1, 3)


# --------------------------------------------------------------------------------------------------
# Bad input raises the documented exceptions.

def test_bad_input_raises_input_error(case):
    db, m, q, ref = case
    uv, light, view = q["uv"][:10], q["light"][:10], q["view"][:10]
    with pytest.raises(btfvq.InputError, match="shape"):
        m.evaluate(uv, np.zeros((10, 4)), view)
    with pytest.raises(btfvq.InputError, match="shape"):
        m.evaluate(uv[:, :1], light, view)
    with pytest.raises(btfvq.InputError, match="lengths"):
        m.evaluate(uv, light[:9], view)
    bad = light.copy()
    bad[3, 1] = np.nan
    with pytest.raises(btfvq.InputError, match=r"light\[3\] is not finite"):
        m.evaluate(uv, bad, view)
    with pytest.raises(btfvq.InputError, match="not finite"):
        m.sample(uv, view, np.full((10, 2), np.inf))
    with pytest.raises(btfvq.InputError, match="zero vector"):
        m.pdf(uv, np.zeros((10, 3)), view)
    with pytest.raises(btfvq.InputError, match="dtype"):
        m.albedo(np.array([["a", "b"]]), view[:1])
    with pytest.raises(ValueError):  # InputError is a ValueError too
        m.evaluate(uv, light, np.zeros((10, 3, 1)))
    e = pytest.raises(btfvq.Error, m.evaluate, uv, None, view).value
    assert isinstance(e, btfvq.InputError) and e.code == "invalid_input"


def test_lookup_and_open_errors(tmp_path):
    db = btfvq.open(BTFBASE / "alu")
    with pytest.raises(btfvq.NotFoundError, match="wood") as e:
        db["wood"]
    assert isinstance(e.value, LookupError) and e.value.code == "not_found"
    with pytest.raises(btfvq.NotFoundError):
        db[3]
    with pytest.raises(btfvq.InputError, match="does not exist|cannot|missing"):
        btfvq.open(tmp_path / "nothing.btfdb")
    assert issubclass(btfvq.ConfigError, btfvq.InputError)
    for cls in (btfvq.InputError, btfvq.CorruptError, btfvq.NotFoundError, btfvq.DeviceError, btfvq.CancelledError):
        assert issubclass(cls, btfvq.Error)


def test_bad_input_does_not_crash_the_interpreter(tmp_path):
    damaged = tmp_path / "damaged.btfdb"
    damaged.write_bytes(b"BTFVQDB\0" + bytes(range(256)) * 4)
    script = f"""
import numpy as np, btfvq
m = btfvq.open({str(BTFBASE / 'alu')!r})['alu']
for call in [lambda: m.evaluate(np.full((5, 2), np.nan), [0, 0, 1], [0, 0, 1]),
             lambda: m.sample(np.zeros((5, 7)), [0, 0, 1], [0.5, 0.5]),
             lambda: m.albedo([0, 0], [np.nan, 0, 1]),
             lambda: btfvq.open({str(damaged)!r}),
             lambda: btfvq.read_sample({str(damaged)!r})]:
    try:
        call()
        raise SystemExit('no exception')
    except btfvq.Error as e:
        print(type(e).__name__)
print(m.evaluate([0.5, 0.5], [0, 0, 1], [0, 0, 1]).shape)
"""
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["InputError", "InputError", "InputError", "CorruptError", "InputError", "(3,)"]


# --------------------------------------------------------------------------------------------------
# Samples as arrays: read, decode, compress.

def png_bytes(rgb):
    h, w, _ = rgb.shape
    raw = b"".join(b"\0" + rgb[y].astype(np.uint8).tobytes() for y in range(h))

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def test_read_sample_zip_and_folder(tmp_path):
    rng = np.random.default_rng(7)
    views, lights = [(10, 20), (35, 200)], [(0, 0), (25, 40), (50, 310)]
    images = {(v, l): rng.integers(0, 256, (5, 4, 3), dtype=np.uint8) for v in views for l in lights}
    zpath, folder = tmp_path / "tiny.zip", tmp_path / "tiny"
    with zipfile.ZipFile(zpath, "w") as z:
        for (v, l), img in images.items():
            z.writestr(f"tiny/tl{l[0]:03d}_pl{l[1]:03d}_tv{v[0]:03d}_pv{v[1]:03d}.png", png_bytes(img))
            (folder / f"tv{v[0]:03d}").mkdir(parents=True, exist_ok=True)
            (folder / f"tv{v[0]:03d}" / f"tl{l[0]:03d}_pl{l[1]:03d}_tv{v[0]:03d}_pv{v[1]:03d}.png").write_bytes(png_bytes(img))
    z.close()
    calls = []
    for src in (zpath, folder):
        a, vd, ld = btfvq.read_sample(src, progress=lambda d, t: calls.append((d, t)), directions=True)
        assert a.shape == (5, 4, 2, 3, 3) and a.dtype == np.uint8
        assert vd.shape == (2, 2) and ld.shape == (2, 3, 2)
        for i, v in enumerate(map(tuple, vd)):
            for j, l in enumerate(map(tuple, ld[i])):
                np.testing.assert_array_equal(a[:, :, i, j], images[(v, l)])
        assert sorted(map(tuple, vd)) == sorted(views)
    assert calls and calls[-1][0] == calls[-1][1] == 6
    np.testing.assert_array_equal(btfvq.read_sample(zpath), a)
    # A damaged archive and a failing callback.
    damaged = tmp_path / "damaged.zip"
    damaged.write_bytes(zpath.read_bytes()[: zpath.stat().st_size // 2])
    with pytest.raises(btfvq.InputError):
        btfvq.read_sample(damaged)

    def stop(done, total):
        raise KeyError("stop here")

    with pytest.raises(KeyError, match="stop here"):
        btfvq.read_sample(folder, progress=stop)


def test_decode_equals_cpp_evaluate_at_the_measured_directions(tmp_path):
    db = btfvq.open(BTFBASE / "alu")
    m = db["alu"]
    views, lights = np.array([[0, 0], [45, 120]]), np.array([[15, 60], [60, 18], [75, 300]])
    a = m.decode(views=views, lights=lights)
    assert a.shape == (64, 64, 2, 3, 3) and a.dtype == np.uint8
    # The C++ API at texel centres: decode rounds and clamps what evaluate gives.
    rng = np.random.default_rng(3)
    xs, ys = rng.integers(0, 64, 200), rng.integers(0, 64, 200)
    vi, li = rng.integers(0, 2, 200), rng.integers(0, 3, 200)
    q = random_queries(1, 200)
    q["uv"] = np.column_stack([(xs + 0.5) / 64, (ys + 0.5) / 64])
    q["light_ang"], q["view_ang"] = lights[li].astype(float), views[vi].astype(float)
    ref = cpp_values(BTFBASE / "alu", "alu", q, tmp_path, albedo_n=0)
    expected = np.clip(np.round(ref["eval_ang"]), 0, 255)
    got = a[ys, xs, vi, li].astype(float)
    assert np.max(np.abs(got - expected)) <= 1  # the P4 x P6-scale image path vs the full chain
    assert np.mean(got == expected) > 0.95
    full = m.decode()
    assert full.shape == (64, 64, 81, 81, 3) and full.dtype == np.uint8
    # btfvq.bonn81(): (0, 0), then the rings theta 15 (phi step 60), 30 (step 30), ...
    np.testing.assert_array_equal(btfvq.bonn81()[[0, 1, 2, 7]], [[0, 0], [15, 0], [15, 60], [30, 0]])
    np.testing.assert_array_equal(full[:, :, 0, 2], a[:, :, 0, 0])  # view (0, 0), light (15, 60)


def psnr(a, b):
    return 10 * np.log10(255.0 ** 2 / np.mean((a.astype(float) - b.astype(float)) ** 2))


def test_compress_array_round_trip_and_damaged_database(tmp_path):
    alu = btfvq.open(BTFBASE / "alu")["alu"]
    sample = np.ascontiguousarray(alu.decode()[:16, :16])  # a real BTF, 16 x 16 texels, Bonn 81 x 81
    out = tmp_path / "py.btfdb"
    seen = []
    summary = btfvq.compress(sample, db=out, name="alu16", quality=50, progress=lambda p: seen.append(p))
    assert summary["materials"] == 1 and summary["bytes"] == out.stat().st_size
    assert summary["raw_bytes"] == sample.nbytes and summary["ratio"] > 1
    assert summary["added"][0]["name"] == "alu16" and summary["added"][0]["width"] == 16
    stages = {p["stage"] for p in seen}
    assert {"phase1", "write"} <= stages and all(0 <= p["fraction"] <= 1 for p in seen)
    m = btfvq.open(out)["alu16"]
    assert (m.width, m.height, m.hdr) == (16, 16, False)
    back = m.decode()
    assert back.shape == sample.shape
    assert psnr(back, sample) > 25  # the CLI's default settings on a real material
    # A second material joins the same file; a clash of names is an InputError and changes nothing.
    btfvq.compress(sample[:8, :8], db=out, name="alu8", config={"thresholds": {"ssim": {"p4": 0.2}}})
    assert btfvq.open(out).names == ["alu16", "alu8"]
    before = out.read_bytes()
    with pytest.raises(btfvq.InputError):
        btfvq.compress(sample[:8, :8], db=out, name="alu8")
    with pytest.raises(btfvq.ConfigError):
        btfvq.compress(sample[:8, :8], db=out, name="alu9", config={"no_such_key": 1})
    with pytest.raises(btfvq.InputError, match="shape"):
        btfvq.compress(sample[:, :, :, :, :2], db=out, name="alu9")
    assert out.read_bytes() == before
    # An exception in the progress callback cancels and comes back as itself.
    with pytest.raises(ZeroDivisionError):
        btfvq.compress(sample[:8, :8], db=out, name="alu9", progress=lambda p: 1 / 0)
    assert out.read_bytes() == before
    # Damaged copies of the file: truncated, and one byte flipped in the middle.
    truncated, flipped = tmp_path / "truncated.btfdb", tmp_path / "flipped.btfdb"
    truncated.write_bytes(before[: len(before) * 2 // 3])
    mid = bytearray(before)
    mid[len(mid) // 2] ^= 0xFF
    flipped.write_bytes(bytes(mid))
    for bad in (truncated, flipped):
        with pytest.raises(btfvq.CorruptError) as e:
            btfvq.open(bad)
        assert e.value.code == "corrupt"


# --------------------------------------------------------------------------------------------------
# The example.

def test_render_sphere_example_writes_a_png(tmp_path):
    out = tmp_path / "sphere.png"
    r = subprocess.run([sys.executable, str(SOURCE / "examples" / "render_sphere.py"), "--db", str(BTFBASE / "alu"),
                        "--material", "alu", "--size", "64", "--spp", "8", "--out", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    w, h = struct.unpack(">II", data[16:24])
    assert (w, h) == (64, 64)
    # Decode the IDAT stream (8-bit RGB, filter 0 rows as the example writes): the sphere is lit,
    # the corners are background.
    idat, pos = b"", 8
    while pos < len(data):
        length, tag = struct.unpack(">I4s", data[pos:pos + 8])
        if tag == b"IDAT":
            idat += data[pos + 8:pos + 8 + length]
        pos += 12 + length
    rows = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(64, 1 + 64 * 3)
    assert np.all(rows[:, 0] == 0)
    img = rows[:, 1:].reshape(64, 64, 3)
    assert img[32, 32].mean() > 20 and np.all(img[0, 0] == img[0, 1])


def test_compare_materials_example_writes_a_png(tmp_path):
    out = tmp_path / "compare.png"
    r = subprocess.run([sys.executable, str(SOURCE / "examples" / "compare_materials.py"), "--size", "32",
                        "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and struct.unpack(">II", data[16:24]) == (4 * 32, 2 * 32)
    assert "alu" in r.stdout and "proposte" in r.stdout


def test_calls_release_the_gil():
    import threading
    m = btfvq.open(BTFBASE / "alu")["alu"]
    q = random_queries(5, 3000)
    done = threading.Event()
    worker = threading.Thread(target=lambda: (m.albedo(q["uv"], q["view"]), done.set()))
    ticks = 0
    worker.start()
    while not done.is_set():  # Python code runs while the albedo call works (about 2700 / s per core)
        ticks += 1
        time.sleep(0.001)
    worker.join()
    assert ticks > 20
