"""Seeded mutation tests of every reader, through the Python API (issue 10, robustness).

Per format a valid file is written, then ``CASES`` corrupted variants of it: random byte flips,
truncations at random lengths, and header fields inflated to huge sizes, counts or dimensions
(rewritten so the rest of the file stays valid: the container's JSON re-padded to its place, the
PNG header CRC recomputed). Every read must be a clean read or a :class:`btfrs.FormatError`:
never another exception, a Rust panic (``PanicException``), or a read slower than ``SLOW``.
Clean reads of BTFs are checked for their shape, clean container reads for arrays that fit the
file, and a clean analysis is used for a small synthesis, which must not fail either.

The formats: ``.btfrs`` BTFs (``Btf.load`` with and without ``mmap``, ``btfrs.load``), fitted
models at the container level (``read_container``), synthesis analyses end to end
(``btfrs.synth.Analysis.load``, then k-coherence and the jump map), ``.ptm`` (LRGB and RGB), PNG
and EXR (``btfrs.io.load_image``), and the index files of glTF assets and Mitsuba scenes (their
valid maps beside them). Every case derives from ``SEED``; a failure names the format,
the case, its seed and the mutation. The allocation bound is measured in the Rust suite
(``rust/btfrs-io/tests/mutation.rs``, a counting allocator); here every array a clean read
returns must fit in the file.
"""

from __future__ import annotations

import json
import os
import random
import struct
import time
import warnings
import zlib

import numpy as np
import pytest
import zipfile
from PIL import Image

import btfrs
from btfrs.btf import read_container
from btfrs.exceptions import FormatError

SEED = 0xB7F50010
CASES = 300
SLOW = 2.0

HUGE_DECIMAL = ["0", "1", "65536", "4294967295", "4294967296", "9223372036854775807", "18446744073709551615",
                "18446744073709551616", "99999999999999999999999", "-1", "1e300"]
HUGE_U32 = [0, 1, 65535, 65536, 1 << 20, 1 << 24, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF]


# --- valid files ------------------------------------------------------------------------------

def _directions(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    theta = rng.uniform(0.0, 1.2, n)
    phi = rng.uniform(0.0, 2 * np.pi, n)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)


def _small_btf() -> btfrs.Btf:
    rng = np.random.default_rng(3)
    views, lights = _directions(3, 1), _directions(8, 2)
    data = rng.uniform(0.0, 1.0, (3, 4, 3, 8, 3)).astype(np.float32)
    mask = np.ones((3, 8), bool)
    mask[1, 2] = False
    return btfrs.Btf(data, views, lights, mask)


def _ptm_bytes(fmt: str) -> bytes:
    w, h = 5, 3
    rng = np.random.default_rng(4)
    per = 9 if fmt == "LRGB" else 18
    head = f"PTM_1.2\nPTM_FORMAT_{fmt}\n{w}\n{h}\n2.5 1.5 1 0.75 0.5 1.25\n10 -3 128 0 255 7\n".encode()
    return head + rng.integers(0, 256, w * h * per, dtype=np.uint8).tobytes()


def _svbrdf_arrays() -> dict:
    rng = np.random.default_rng(7)
    n = np.concatenate([rng.uniform(-0.4, 0.4, (4, 5, 2)), np.ones((4, 5, 1))], -1)
    return {"diffuse": rng.uniform(0.0, 1.0, (4, 5, 3)).astype(np.float32),
            "specular": rng.uniform(0.0, 0.5, (4, 5, 3)).astype(np.float32),
            "roughness": rng.uniform(0.05, 0.9, (4, 5)).astype(np.float32),
            "normal": (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)}


@pytest.fixture(scope="module")
def valid(tmp_path_factory) -> dict:
    """The valid file of every format, as bytes."""
    d = tmp_path_factory.mktemp("valid")
    out = {}
    btf = _small_btf()
    btf.save(d / "btf.btfrs")
    out["btf"] = (d / "btf.btfrs").read_bytes()
    for kind, info in btfrs.model_kinds().items():
        m = btfrs.fit.fit(kind, btf, **info["examples"][0][1])
        # The fit's wall time is stored in the file; pinned, so the valid file (and so every
        # mutation of it) is the same bytes on every run and machine.
        m.fit_seconds = 0.0
        m.save(d / f"{kind}.btfrs")
        out[f"model_{kind}"] = (d / f"{kind}.btfrs").read_bytes()
    tex = np.random.default_rng(5).uniform(0.0, 1.0, (16, 16, 3)).astype(np.float32)
    an = btfrs.synth.analyse(tex, textons=16, levels=2, m=4, neighbourhoods=(1,), iterations=3, seed=1)
    an.save(d / "analysis.btfrs")
    out["analysis"] = (d / "analysis.btfrs").read_bytes()
    out["ptm_lrgb"] = _ptm_bytes("LRGB")
    out["ptm_rgb"] = _ptm_bytes("RGB")
    # The renderers' scene formats (folders): the index file is mutated, the maps stay beside it.
    sv = btfrs.Model.from_arrays(_svbrdf_arrays(), kind="svbrdf")
    for fmt, index in (("gltf", "material.gltf"), ("mitsuba", "scene.xml")):
        sv.export(d / fmt, format=fmt)
        out[fmt] = (d / fmt / index).read_bytes()
        out[f"{fmt}_maps"] = {n: (d / fmt / n).read_bytes() for n in os.listdir(d / fmt) if n != index}
    img = np.random.default_rng(6).uniform(0.0, 1.0, (5, 7, 3)).astype(np.float32)
    btfrs.io.save_image(d / "a.png", img)
    out["png"] = (d / "a.png").read_bytes()
    btfrs.io.save_image(d / "a.exr", img)
    out["exr"] = (d / "a.exr").read_bytes()
    # Measured captures: a JPEG photograph (read through a one-image .lp set), an .lp file (its
    # images beside it), a UBO2003 zip archive.
    px = (np.random.default_rng(7).uniform(0, 1, (12, 16, 3)) * 255).astype(np.uint8)
    io_bytes = __import__("io").BytesIO()
    Image.fromarray(px).save(io_bytes, format="JPEG", quality=90)
    out["jpeg"] = io_bytes.getvalue()
    out["lp"] = ("3\n" + "".join(f"l{i}.png {x} {y} {z}\n" for i, (x, y, z) in enumerate(_directions(3, 4)))).encode()
    zb = __import__("io").BytesIO()
    with zipfile.ZipFile(zb, "w", zipfile.ZIP_DEFLATED) as z:
        for i, (tl, pl) in enumerate([(0, 0), (30, 90), (60, 180)]):
            b = __import__("io").BytesIO()
            Image.fromarray(np.roll(px, i, axis=0)).save(b, format="PNG")
            z.writestr(f"m_{i:05d}_tl{tl:03d}_pl{pl:03d}_tv000_pv000.png", b.getvalue())
    out["zip"] = zb.getvalue()
    return out


# --- mutations --------------------------------------------------------------------------------

def _numbers(text: bytes, start: int = 0):
    """Byte ranges of the numbers in ``text`` that follow ``[``, ``,``, ``:`` or whitespace."""
    out, i = [], start
    while i < len(text):
        c = text[i:i + 1]
        if (c.isdigit() or c == b"-") and (i == 0 or text[i - 1:i] in (b"[", b",", b":", b" ", b"\n", b"\r")):
            j = i + 1
            while j < len(text) and (text[j:j + 1].isdigit() or text[j:j + 1] in b".eE+-"):
                j += 1
            out.append((i, j))
            i = j
        else:
            i += 1
    return out


def _inflate_container(f: bytes, rng: random.Random):
    (hlen,) = struct.unpack_from("<Q", f, 8)
    if rng.randrange(8) == 0:
        v = rng.choice(HUGE_U32) << rng.randrange(33)
        return f[:8] + struct.pack("<Q", v) + f[16:], f"header length := {v}"
    text = f[16:16 + hlen]
    if rng.randrange(4) == 0:
        a = rng.choice([b'"f32"', b'"u16"', b'"f64"', b'"i32"', b'"bool"', b'"u8"'])
        b = rng.choice([b'"f64"', b'"u8"', b'"f32"', b'"bool"', b'"f16"'])
        new, what = text.replace(a, b, 1), f"dtype {a.decode()} := {b.decode()}"
    else:
        a, b = rng.choice(_numbers(text))
        v = rng.choice(HUGE_DECIMAL)
        new, what = text[:a] + v.encode() + text[b:], f"header number {text[a:b].decode()} at {a} := {v}"
    # Keep the arrays where they are: the data start at the first 64-byte boundary after the
    # header; pad the new header with JSON whitespace up to there when it fits.
    start = -(-(16 + hlen) // 64) * 64
    if len(new) <= start - 16:
        new = new.ljust(start - 16, b" ")
    return f[:8] + struct.pack("<Q", len(new)) + new + f[min(start, 16 + len(new)):], what


def _inflate_ptm(f: bytes, rng: random.Random):
    end = 0
    for _ in range(6):
        end = f.index(b"\n", end) + 1
    nums = _numbers(f[:end])
    k = rng.randrange(len(nums))
    a, b = nums[k]
    v = rng.choice(HUGE_DECIMAL) if k < 2 else rng.choice(
        ["1e38", "3.4e38", "1e300", "-1e300", "nan", "inf", "1e-45", "0", "-0"])
    return f[:a] + v.encode() + f[b:], f"header field {k} {f[a:b].decode()} := {v}"


def _inflate_png(f: bytes, rng: random.Random):
    g = bytearray(f)
    kind = rng.randrange(4)
    if kind == 3:
        v = rng.choice(HUGE_U32)
        g[33:37] = struct.pack(">I", v)
        return bytes(g), f"second chunk length := {v}"
    if kind == 2:
        d, c = rng.choice([1, 2, 4, 8, 16, 32, 255]), rng.choice([0, 2, 3, 4, 6, 7, 255])
        g[24], g[25] = d, c
        what = f"IHDR depth, colour := {d}, {c}"
    else:
        w, h = rng.choice(HUGE_U32), rng.choice(HUGE_U32)
        g[16:24] = struct.pack(">II", w, h)
        what = f"IHDR size := {w} x {h}"
    g[29:33] = struct.pack(">I", zlib.crc32(bytes(g[12:29])))
    return bytes(g), what


def _exr_layout(f: bytes):
    """Header attributes ``(name, type, value offset)`` and the chunk offset table entries."""
    at, attrs, rows, per_chunk = 8, [], 0, 1
    while f[at] != 0:
        n = f.index(b"\0", at)
        name = f[at:n].decode()
        t = f.index(b"\0", n + 1)
        ty = f[n + 1:t].decode()
        (size,) = struct.unpack_from("<i", f, t + 1)
        val = t + 5
        if name == "dataWindow":
            _, y0, _, y1 = struct.unpack_from("<4i", f, val)
            rows = y1 - y0 + 1
        if name == "compression":
            per_chunk = 1 if f[val] <= 2 else 16 if f[val] in (3, 5) else 32
        attrs.append((name, ty, val))
        at = val + size
    chunks = -(-rows // per_chunk)
    return attrs, [at + 1 + 8 * i for i in range(chunks)]


def _inflate_exr(f: bytes, rng: random.Random):
    g = bytearray(f)
    attrs, offsets = _exr_layout(f)
    if rng.randrange(3) == 0 and offsets:
        at = rng.choice(offsets)
        v = rng.choice(HUGE_U32) << rng.randrange(33)
        g[at:at + 8] = struct.pack("<Q", v)
        return bytes(g), f"chunk offset at {at} := {v}"
    name, _, at = rng.choice([a for a in attrs if a[1] == "box2i" and a[0].endswith("Window")])
    field = rng.randrange(4)
    v = rng.choice([2**31 - 1, -2**31, -1, 0, 1 << 16, 1 << 20, 1 << 30, 100_000])
    g[at + 4 * field:at + 4 * field + 4] = struct.pack("<i", v)
    return bytes(g), f"{name} field {field} := {v}"


def _inflate_jpeg(f: bytes, rng: random.Random):
    g = bytearray(f)
    sof = g.index(b"\xff\xc0")
    h, w = rng.choice(HUGE_U32) & 0xFFFF, rng.choice(HUGE_U32) & 0xFFFF
    g[sof + 5:sof + 9] = struct.pack(">HH", h, w)
    return bytes(g), f"SOF0 height, width := {h}, {w}"


def _inflate_lp(f: bytes, rng: random.Random):
    nums = _numbers(f)
    k = rng.randrange(len(nums))
    a, b = nums[k]
    v = rng.choice(HUGE_DECIMAL + ["1e200", "-1e200", "nan", "inf", "1e-200"])
    return f[:a] + v.encode() + f[b:], f"number {k} {f[a:b].decode()} := {v}"


def _inflate_zip(f: bytes, rng: random.Random):
    g = bytearray(f)
    v = rng.choice(HUGE_U32)
    # every local header's and central directory entry's uncompressed size
    for sig, off in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):
        i = g.find(sig)
        while i >= 0:
            g[i + off:i + off + 4] = struct.pack("<I", v)
            i = g.find(sig, i + 4)
    return bytes(g), f"declared uncompressed sizes := {v}"


INFLATE = {"jpeg": _inflate_jpeg, "lp": _inflate_lp, "zip": _inflate_zip, "btf": _inflate_container, **{f"model_{k}": _inflate_container for k in btfrs.model_kinds()},
           "analysis": _inflate_container,
           "ptm_lrgb": _inflate_ptm, "ptm_rgb": _inflate_ptm, "png": _inflate_png, "exr": _inflate_exr,
           "gltf": _inflate_lp, "mitsuba": _inflate_lp}


def mutate(fmt: str, f: bytes, seed: int):
    """One corrupted variant of ``f`` and what was done, from the case's own seed."""
    rng = random.Random(seed)
    kind = rng.randrange(3)
    if kind == 0:
        g = bytearray(f)
        flips = []
        for _ in range(1 + rng.randrange(8)):
            i, x = rng.randrange(len(g)), 1 + rng.randrange(255)
            g[i] ^= x
            flips.append(f"{i}^{x:#04x}")
        return bytes(g), "flip bytes " + " ".join(flips)
    if kind == 1:
        n = rng.randrange(len(f))
        return f[:n], f"truncate to {n} of {len(f)} bytes"
    return INFLATE[fmt](f, rng)


# --- readers ----------------------------------------------------------------------------------

def _fits_file(path, arrays: dict) -> None:
    total = sum(a.nbytes for a in arrays.values())
    assert total <= os.path.getsize(path), f"arrays of {total} bytes from a {os.path.getsize(path)}-byte file"


def read_btf(path) -> None:
    for mmap in (False, True):
        b = btfrs.Btf.load(path, mmap=mmap)
        assert b.data.ndim == 5 and b.data.shape[-1] == 3 and b.views.shape == (b.n_views, 3)
        _fits_file(path, {"data": b.data})
        del b
    assert isinstance(btfrs.load(path), btfrs.Btf)


def read_model(path) -> None:
    # End to end through the model layer (btfrs-io's model file + the model's own from_arrays):
    # a clean read must be a usable model whose evaluation is finite where its values are.
    kind, meta, arrays = read_container(path)
    assert isinstance(kind, str) and isinstance(meta, dict)
    _fits_file(path, arrays)
    m = btfrs.load(path)
    assert isinstance(m, btfrs.Model)
    try:
        img = m.evaluate([0.1, 0.2, 0.97], [0.3, -0.2, 0.93])
    except btfrs.exceptions.NumericalError as e:
        # Finite stored values that overflow when evaluated (a flipped exponent bit): refused
        # by name, never returned as Inf or NaN.
        assert "non-finite" in str(e) and "largest stored value" in str(e), e
        return
    assert img.shape == (m.height, m.width, 3) and np.isfinite(img).all()


def read_analysis(path) -> None:
    an = btfrs.synth.Analysis.load(path)
    # A clean read must be usable: the synthesis may refuse it with a btfrs error (e.g. a
    # level too small for the window), but never crash.
    try:
        btfrs.synth.kcoherence(an, size=(12, 12), k=2, neighbourhood=1, levels=an.levels, seed=1)
        btfrs.synth.jump_map(an, size=(12, 12), neighbourhood=1, seed=1)
    except btfrs.exceptions.BtfrsError as e:
        if isinstance(e, btfrs.exceptions.InternalError):
            raise


def read_ptm(path) -> None:
    btfrs.load(path)


def read_image(path) -> None:
    img = btfrs.io.load_image(path)
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.float32


def _beside(path) -> None:
    """The PNG images an .lp case names, beside it."""
    d = os.path.dirname(path)
    for i in range(3):
        q = os.path.join(d, f"l{i}.png")
        if not os.path.exists(q):
            Image.fromarray(np.full((4, 5, 3), 40 * i, np.uint8)).save(q)


def read_capture(path) -> None:
    p = os.fspath(path)
    if p.endswith(".jpg"):
        lp = p + ".lp"
        with open(lp, "w") as f:
            f.write(f"1\n{os.path.basename(p)} 0 0 1\n")
        p = lp
    elif p.endswith(".lp"):
        _beside(p)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # non-unit light vectors, normalised
        b = btfrs.load(p)
    assert b.data.ndim == 5 and np.isfinite(b.data).all()


def read_scene(path) -> None:
    """A glTF asset or Mitsuba scene: the mutated index file, the valid maps beside it."""
    fmt = "gltf" if os.fspath(path).endswith(".gltf") else "mitsuba"
    for name, data in _MAPS[fmt].items():
        q = os.path.join(os.path.dirname(path), name)
        if not os.path.exists(q):
            with open(q, "wb") as f:
                f.write(data)
    m = btfrs.load(path)
    assert m.kind == "svbrdf"
    img = m.evaluate([0.1, 0.2, 0.97], [0.3, -0.2, 0.93])
    assert np.isfinite(img).all()


_MAPS: dict = {}

READERS = {"jpeg": (read_capture, ".jpg"), "lp": (read_capture, ".lp"), "zip": (read_capture, ".zip"),
           "btf": (read_btf, ".btfrs"), **{f"model_{k}": (read_model, ".btfrs") for k in btfrs.model_kinds()},
           "analysis": (read_analysis, ".btfrs"),
           "ptm_lrgb": (read_ptm, ".ptm"), "ptm_rgb": (read_ptm, ".ptm"), "png": (read_image, ".png"),
           "exr": (read_image, ".exr"), "gltf": (read_scene, ".gltf"), "mitsuba": (read_scene, ".xml")}


@pytest.mark.parametrize("fmt", list(READERS))
def test_corrupted_files_read_cleanly_or_raise_format_error(fmt, valid, tmp_path):
    read, ext = READERS[fmt]
    _MAPS.update({k: valid[f"{k}_maps"] for k in ("gltf", "mitsuba")})
    ok = tmp_path / f"valid{ext}"
    ok.write_bytes(valid[fmt])
    read(ok)  # the valid file reads
    base = SEED ^ (sorted(READERS).index(fmt) * 0x10000001)
    failures, errors, t_total = [], 0, time.perf_counter()
    for i in range(CASES):
        seed = base + i
        data, what = mutate(fmt, valid[fmt], seed)
        # A new file per case: a mapped array of the previous case must not see this one.
        p = tmp_path / f"case{i}{ext}"
        p.write_bytes(data)
        case = f"{fmt} case {i} (seed {seed:#x}, {len(data)} bytes): {what}"
        t0 = time.perf_counter()
        try:
            read(p)
        except FormatError:
            errors += 1
        except BaseException as e:  # noqa: B902 - a Rust panic is a BaseException
            if isinstance(e, KeyboardInterrupt):
                raise
            failures.append(f"{case}: {type(e).__name__}: {e}")
        took = time.perf_counter() - t0
        if took > SLOW:
            failures.append(f"{case}: took {took:.1f} s")
        p.unlink()
    assert not failures, f"{len(failures)} of {CASES} cases failed:\n" + "\n".join(failures)
    # Most mutations must reach the checks behind the first bytes, not only the magic number.
    assert errors > CASES // 4
    print(f"{fmt}: {CASES} mutated files, {CASES - errors} clean, {errors} FormatError, "
          f"{time.perf_counter() - t_total:.2f} s")


# --- targeted regressions ---------------------------------------------------------------------

def _rewrite_header(path, edit) -> None:
    """Replace a container's JSON header by ``edit(header)``, keeping the data in place."""
    f = path.read_bytes()
    (hlen,) = struct.unpack_from("<Q", f, 8)
    start = -(-(16 + hlen) // 64) * 64
    new = json.dumps(edit(json.loads(f[16:16 + hlen]))).encode()
    assert len(new) <= start - 16
    path.write_bytes(f[:8] + struct.pack("<Q", start - 16) + new.ljust(start - 16, b" ") + f[start:])


def test_inflated_png_header_is_rejected_before_allocating(valid, tmp_path):
    # A 100000 x 100000 header with a valid CRC in a file of a few hundred bytes: the reader used
    # to allocate the 30 GB the header declares (an abort, not an exception).
    g = bytearray(valid["png"])
    g[16:24] = struct.pack(">II", 100_000, 100_000)
    g[29:33] = struct.pack(">I", zlib.crc32(bytes(g[12:29])))
    p = tmp_path / "big.png"
    p.write_bytes(bytes(g))
    with pytest.raises(FormatError, match="100000 x 100000"):
        btfrs.io.load_image(p)


def test_btf_files_record_finite_data_and_mmap_trusts_it(tmp_path):
    btf = _small_btf()
    p = tmp_path / "b.btfrs"
    btf.save(p)
    kind, meta, infos = btfrs._native.read_container_header(str(p))
    flags = {name: fin for name, _, _, _, fin in infos}
    assert flags == {"data": True, "views": True, "lights": True, "mask": None}

    # Make the flag lie: NaN in the data section after writing. A load that scanned the data
    # would see it; mmap trusts the flag and reads no data page, the in-memory load still scans.
    (hlen,) = struct.unpack_from("<Q", p.read_bytes(), 8)
    offset = next(off for name, _, _, off, _ in infos if name == "data")
    with open(p, "r+b") as f:
        f.seek(offset + 4 * 7)
        f.write(np.float32(np.nan).tobytes())
    mapped = btfrs.Btf.load(p, mmap=True)
    assert np.isnan(mapped.data.reshape(-1)[7]) and np.isfinite(np.delete(mapped.data.reshape(-1), 7)).all()
    with pytest.raises(FormatError, match="not finite"):
        btfrs.Btf.load(p)
    # The fits scan their input: the NaN surfaces as an error there, not as a NaN model. PTM,
    # HSH, SRF and Lafortune check each texel in their own pass (one read of a mapped file),
    # the others (SH here) scan before fitting; the error is the same.
    for kind in ("ptm", "hsh", "srf", "lafortune", "sh"):
        with pytest.raises(btfrs.exceptions.InvalidArgumentError, match=r"^data: value NaN at flat index 7 is not finite"):
            btfrs.fit.fit(kind, mapped)
    del mapped

    # A file without the flag (as written before it existed) is scanned with mmap too.
    _rewrite_header(p, lambda h: {**h, "arrays": [{k: v for k, v in a.items() if k != "finite"}
                                                 for a in h["arrays"]]})
    assert all(fin is None for *_, fin in btfrs._native.read_container_header(str(p))[2])
    with pytest.raises(FormatError, match="not finite"):
        btfrs.Btf.load(p, mmap=True)
    # ... and loads when its values are finite.
    with open(p, "r+b") as f:
        f.seek(offset + 4 * 7)
        f.write(btf.data.reshape(-1)[7:8].tobytes())
    np.testing.assert_array_equal(btfrs.Btf.load(p, mmap=True).data, btf.data)


def test_mmap_load_of_a_flagged_file_does_not_scan(tmp_path, monkeypatch):
    p = tmp_path / "b.btfrs"
    _small_btf().save(p)
    calls = []
    real = btfrs._native.validate_btf

    def spy(*args, scan_values=True, **kw):
        calls.append(scan_values)
        return real(*args, scan_values=scan_values, **kw)

    monkeypatch.setattr(btfrs.btf._native, "validate_btf", spy)
    btfrs.Btf.load(p, mmap=True)
    btfrs.Btf.load(p)
    assert calls == [False, True]


def test_saving_non_finite_data_writes_nothing(tmp_path):
    btf = _small_btf()
    bad = btf.data.copy()
    bad[1, 2, 0, 3, 1] = np.inf
    p = tmp_path / "bad.btfrs"
    with pytest.raises(btfrs.exceptions.InvalidArgumentError, match="data"):
        btfrs.Btf(bad, btf.views, btf.lights, check=False).save(p)
    assert list(tmp_path.iterdir()) == []


def test_inconsistent_analysis_pyramid_is_a_format_error(valid, tmp_path):
    p = tmp_path / "an.btfrs"
    p.write_bytes(valid["analysis"])
    kind, meta, arrays = read_container(p)
    assert kind == "analysis" and arrays["level1.textons"].shape == (8, 8)

    def save(arrs, path):
        btfrs._native.save_container(str(path), kind, json.dumps(meta),
                                     [(k, np.ascontiguousarray(v)) for k, v in arrs.items()])

    # Level 1 replaced by a copy of level 0: not half of it (k-coherence would read it with the
    # wrong width). Before the check this loaded and synthesized garbage.
    bad = dict(arrays)
    for name in [k for k in arrays if k.startswith("level1.")]:
        bad[name] = arrays[name.replace("level1.", "level0.")]
    save(bad, tmp_path / "same.btfrs")
    with pytest.raises(FormatError, match=r"level1\.textons.*expected 8 x 8"):
        btfrs.synth.Analysis.load(tmp_path / "same.btfrs")
    # A similar-neighbourhood entry on the border of the level: the synthesis would read its
    # window outside the level.
    bad = dict(arrays)
    idx = arrays["level0.similar1.index"].copy()
    idx[5, 5, 0] = 0
    bad["level0.similar1.index"] = idx
    save(bad, tmp_path / "border.btfrs")
    with pytest.raises(FormatError, match=r"level0\.similar1\.index.*not an interior pixel"):
        btfrs.synth.Analysis.load(tmp_path / "border.btfrs")
    # Negative option values are a FormatError too (they used to leak an OverflowError).
    meta2 = {**meta, "options": {**meta["options"], "m": -4}}
    btfrs._native.save_container(str(tmp_path / "neg.btfrs"), kind, json.dumps(meta2),
                                 [(k, np.ascontiguousarray(v)) for k, v in arrays.items()])
    with pytest.raises(FormatError, match="options"):
        btfrs.synth.Analysis.load(tmp_path / "neg.btfrs")
