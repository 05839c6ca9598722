"""Measured data in: UBO2003 / ATRIUM archives, RTI .lp sets, image stacks with direction tables,
UBO2014 .btf (DFMF), EXR in and out, crops, subsets, streaming to disk, and the bad input of each.

Every capture is made here (no downloads) from a Lambertian relief whose shading follows from
its own light direction, so a direction mapped to the wrong axis (or rows read upside down)
shows as a value that disagrees with the closed form, not only as a wrong label.
"""

from __future__ import annotations

import json
import math
import os
import struct
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import btfrs
from btfrs import io
from btfrs.exceptions import BtfrsError, FormatError, InvalidArgumentError

H, W = 12, 16


def relief_normals(h: int = H, w: int = W) -> np.ndarray:
    """Normals [h, w, 3] of a bump field in btfrs's frame: x along the columns, y *up* the
    image (towards row 0)."""
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    height = 2.0 * np.exp(-((cols - w * 0.35) ** 2 + (rows - h * 0.4) ** 2) / 10.0) \
        + 1.5 * np.exp(-((cols - w * 0.75) ** 2 + (rows - h * 0.7) ** 2) / 6.0)
    dh_dx = np.gradient(height, axis=1)
    dh_dy = -np.gradient(height, axis=0)  # y grows up the image: rows decrease
    n = np.stack([-dh_dx, -dh_dy, np.ones_like(height)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def albedo(h: int = H, w: int = W) -> np.ndarray:
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.stack([0.3 + 0.6 * cols / w, 0.3 + 0.6 * (h - 1 - rows) / h, np.full_like(cols, 0.6)], axis=-1)


def shade(light, view=(0, 0, 1)) -> np.ndarray:
    """Linear RGB [H, W, 3] of the relief under ``light`` (Lambertian: albedo x max(0, n.l),
    cos included as measured BTFs hold it); the view only scales it slightly, so that views
    differ too."""
    n = relief_normals()
    l = np.asarray(light, dtype=np.float64)
    l = l / np.linalg.norm(l)
    v = np.asarray(view, dtype=np.float64)
    return albedo() * np.clip(n @ l, 0, None)[..., None] * (0.8 + 0.2 * v[2])


def to_srgb8(lin: np.ndarray) -> np.ndarray:
    x = np.clip(lin, 0, 1)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    return np.round(s * 255).astype(np.uint8)


def srgb8_to_linear(b: np.ndarray) -> np.ndarray:
    x = b.astype(np.float64) / 255
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def direction(theta, phi):
    t, p = math.radians(theta), math.radians(phi)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


UBO_VIEWS = [(0, 0), (30, 90), (30, 270)]
UBO_LIGHTS = [(0, 0), (45, 0), (45, 90), (45, 180), (45, 270), (75, 60)]


def ubo_name(i, tl, pl, tv, pv, ext="png"):
    return f"TestCloth256_{i:05d}_tl{tl:03d}_pl{pl:03d}_tv{tv:03d}_pv{pv:03d}.{ext}"


def write_ubo(folder, ext="png", zip_path=None, skip=()):
    """A UBO-style archive of the relief: one image per (view, light), angles in the names."""
    os.makedirs(folder, exist_ok=True)
    files, i = [], 0
    for tv, pv in UBO_VIEWS:
        for tl, pl in UBO_LIGHTS:
            i += 1
            if (tv, pv, tl, pl) in skip:
                continue
            name = ubo_name(i, tl, pl, tv, pv, ext)
            img = shade(direction(tl, pl), direction(tv, pv))
            p = os.path.join(folder, name)
            if ext == "exr":
                io.save_image(p, img.astype(np.float32))
            else:
                Image.fromarray(to_srgb8(img)).save(p, quality=95) if ext == "jpg" else Image.fromarray(to_srgb8(img)).save(p)
            files.append(p)
    if zip_path:
        with zipfile.ZipFile(zip_path, "w", compression=zipfile.ZIP_DEFLATED) as z:
            for p in files:
                z.write(p, arcname=f"TestCloth256/{os.path.basename(p)}")
    return files


def expected_btf_values(views, lights, quantize=True):
    out = np.zeros((H, W, len(views), len(lights), 3))
    for vi, v in enumerate(views):
        for li, l in enumerate(lights):
            img = shade(l, v)
            out[:, :, vi, li] = srgb8_to_linear(to_srgb8(img)) if quantize else img
    return out


# --- UBO2003 / ATRIUM ---------------------------------------------------------------------------

def test_ubo_zip_and_folder_load_in_theta_phi_order_with_values_of_the_relief(tmp_path):
    folder = tmp_path / "imgs"
    write_ubo(folder, zip_path=tmp_path / "TestCloth256.zip")
    for src in (tmp_path / "TestCloth256.zip", folder):
        btf = io.load(src)
        assert isinstance(btf, btfrs.Btf) and btf.shape == (H, W, 3, 6, 3) and btf.mask is None
        want_v = sorted(UBO_VIEWS)
        want_l = sorted(UBO_LIGHTS)
        np.testing.assert_allclose(btf.views, [direction(*a) for a in want_v], atol=1e-6)
        np.testing.assert_allclose(btf.lights, [direction(*a) for a in want_l], atol=1e-6)
        ref = expected_btf_values(btf.views, btf.lights)
        # 8-bit sRGB decoded exactly (float32 of the same curve)
        np.testing.assert_allclose(btf.data, ref, atol=2e-6)


def test_ubo_orientation_phi_zero_lights_the_slopes_facing_plus_x_and_ninety_those_facing_up(tmp_path):
    write_ubo(tmp_path / "a")
    btf = io.load(tmp_path / "a")
    n = relief_normals()
    lum = btf.data[:, :, 0].mean(axis=-1)  # view at the normal
    li = {tuple(np.round(l, 6)): k for k, l in enumerate(btf.lights)}
    east = lum[:, :, li[tuple(np.round(direction(45, 0), 6))]]
    north = lum[:, :, li[tuple(np.round(direction(45, 90), 6))]]
    west = lum[:, :, li[tuple(np.round(direction(45, 180), 6))]]
    facing_x = n[..., 0] > 0.2
    facing_minus_x = n[..., 0] < -0.2
    facing_up = n[..., 1] > 0.2  # towards row 0
    facing_down = n[..., 1] < -0.2
    assert east[facing_x].mean() > 1.3 * east[facing_minus_x].mean()
    assert west[facing_minus_x].mean() > 1.3 * west[facing_x].mean()
    assert north[facing_up].mean() > 1.3 * north[facing_down].mean()
    # and the slopes facing up the image are in the upper rows of this relief's first bump
    rows_up = np.nonzero(facing_up[:, :8])[0]
    rows_down = np.nonzero(facing_down[:, :8])[0]
    assert rows_up.mean() < rows_down.mean()


def test_ubo_jpeg_and_exr_variants(tmp_path):
    write_ubo(tmp_path / "j", ext="jpg")
    b = io.load(tmp_path / "j")
    ref = expected_btf_values(b.views, b.lights, quantize=False)
    assert np.abs(b.data - ref).mean() < 0.01  # JPEG at quality 95
    write_ubo(tmp_path / "e", ext="exr")
    e = io.load(tmp_path / "e")
    np.testing.assert_allclose(e.data, expected_btf_values(e.views, e.lights, quantize=False), atol=1e-6)


def test_ubo_crop_and_subsets_equal_slices_of_the_full_load(tmp_path):
    write_ubo(tmp_path / "a")
    full = io.load(tmp_path / "a")
    part = io.load(tmp_path / "a", crop=(2, 3, 5, 7), views=[2, 0], lights=[5, 1, 3])
    np.testing.assert_array_equal(part.data, full.data[2:7, 3:10][:, :, [2, 0]][:, :, :, [5, 1, 3]])
    np.testing.assert_array_equal(part.views, full.views[[2, 0]])
    np.testing.assert_array_equal(part.lights, full.lights[[5, 1, 3]])


def test_ubo_missing_pairs_are_masked(tmp_path):
    write_ubo(tmp_path / "a", skip={(30, 90, 45, 180)})
    b = io.load(tmp_path / "a")
    assert b.mask is not None and b.pairs == 17
    v = [k for k, d in enumerate(b.views) if np.allclose(d, direction(30, 90))][0]
    l = [k for k, d in enumerate(b.lights) if np.allclose(d, direction(45, 180))][0]
    assert not b.mask[v, l] and np.all(b.data[:, :, v, l] == 0)


def test_ubo_bad_input_names_the_file(tmp_path):
    d = tmp_path / "a"
    write_ubo(d)
    Image.fromarray(np.zeros((H, W, 3), np.uint8)).save(d / "TestCloth256_09999_tl015_pl000.png")
    with pytest.raises(FormatError, match=r"tl015_pl000\.png.*(angles|tv)"):
        io.load(d)
    os.remove(d / "TestCloth256_09999_tl015_pl000.png")
    Image.fromarray(np.zeros((H + 1, W, 3), np.uint8)).save(d / ubo_name(99, 60, 0, 0, 0))
    with pytest.raises(FormatError, match=r"00099.*13 x 16.*expected 12 x 16"):
        io.load(d)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(FormatError, match="no images"):
        io.load(empty)
    with pytest.raises(InvalidArgumentError, match="crop"):
        io.load(tmp_path / "a", crop=(10, 0, 5, 5))
    with pytest.raises(InvalidArgumentError, match="views: index 7"):
        io.load(tmp_path / "a", views=[7])


# --- RTI .lp ------------------------------------------------------------------------------------

RTI_LIGHTS = [direction(t, p) for t, p in [(10, 0), (35, 30), (35, 150), (50, 250), (60, 320), (70, 90),
                                           (45, 200), (20, 100), (65, 10), (55, 130)]]


def write_lp(folder, *, bits=8, fmt="png", scale=None, missing=False):
    os.makedirs(folder, exist_ok=True)
    lines = [str(len(RTI_LIGHTS))]
    for i, l in enumerate(RTI_LIGHTS):
        img = shade(l)
        name = f"img {i:02d}.{fmt}"
        if bits == 16:
            Image.fromarray(np.round(np.clip(img, 0, 1) * 65535).astype(np.uint16)[..., 0]).save(
                os.path.join(folder, name))
        else:
            Image.fromarray(to_srgb8(img)).save(os.path.join(folder, name))
        shown = name if i % 3 else f"C:\\capture\\jpeg-exports\\{name}"  # written on another machine
        if missing and i == 4:
            shown = "nowhere.png"
        v = l * (scale if (scale and i == 2) else 1.0)
        lines.append(f"{shown} {v[0]:.9f} {v[1]:.9f} {v[2]:.9f}")
    p = os.path.join(folder, "dirs.lp")
    Path(p).write_text("\n".join(lines) + "\n")
    return p


def test_lp_capture_loads_one_view_with_the_lights_in_file_order(tmp_path):
    p = write_lp(tmp_path / "cap")
    for src in (p, tmp_path / "cap"):
        b = io.load(src)
        assert b.shape == (H, W, 1, 10, 3)
        np.testing.assert_allclose(b.views, [[0, 0, 1]])
        np.testing.assert_allclose(b.lights, RTI_LIGHTS, atol=1e-8)
        for k, l in enumerate(RTI_LIGHTS):
            np.testing.assert_allclose(b.data[:, :, 0, k], srgb8_to_linear(to_srgb8(shade(l))), atol=2e-6)


def test_lp_orientation_y_points_up_the_image(tmp_path):
    b = io.load(write_lp(tmp_path / "cap"))
    n = relief_normals()
    k = 5  # light at theta 70, phi 90: from the top of the image
    lum = b.data[:, :, 0, k].mean(-1)
    assert lum[n[..., 1] > 0.2].mean() > 1.5 * lum[n[..., 1] < -0.2].mean()


def test_lp_sixteen_bit_linear_tiff_and_warning_for_non_unit_vectors(tmp_path):
    p = write_lp(tmp_path / "t", bits=16, fmt="tif", scale=1.2)
    with pytest.warns(UserWarning, match=r"dirs\.lp: 1 light vector normalised \(length 1\.2\) at line 4$"):
        b = io.load(p, linear=True)
    np.testing.assert_allclose(b.lights, RTI_LIGHTS, atol=1e-8)
    red = np.clip(shade(RTI_LIGHTS[3])[..., 0], 0, 1)
    np.testing.assert_allclose(b.data[:, :, 0, 3, 1], np.round(red * 65535) / 65535, atol=1e-6)  # grey -> RGB


def test_lp_bad_input(tmp_path):
    p = write_lp(tmp_path / "m", missing=True)
    with pytest.raises(FormatError, match=r"dirs\.lp.*line 6.*nowhere\.png"):
        io.load(p)
    p = write_lp(tmp_path / "c")
    text = Path(p).read_text().replace("10\n", "12\n", 1)
    Path(p).write_text(text)
    with pytest.raises(FormatError, match="declares 12 images.*lists 10"):
        io.load(p)


# --- generic stacks, EXR in and out -------------------------------------------------------------

def test_stack_with_csv_and_json_tables_and_exr_round_trip(tmp_path):
    ref = btfrs.materials.make("bumps", size=8, seed=2).select(views=[0, 7, 20], lights=[0, 3, 9, 30, 50])
    table = io.save_stack(ref, tmp_path / "stack")
    back = io.load(tmp_path / "stack", directions=table)
    np.testing.assert_array_equal(back.data, ref.data)  # float EXR: exact
    assert io.capture_kind(tmp_path / "stack") == "table"  # the folder's own directions.csv
    np.testing.assert_array_equal(io.load(tmp_path / "stack").data, ref.data)
    np.testing.assert_allclose(back.views, ref.views, atol=1e-12)
    np.testing.assert_allclose(back.lights, ref.lights, atol=1e-12)
    # the same stack described by angles in a JSON table
    rows = []
    for line in Path(table).read_text().splitlines()[1:]:
        f, vx, vy, vz, lx, ly, lz = line.split(",")
        ang = lambda x, y, z: (math.degrees(math.acos(float(z))), math.degrees(math.atan2(float(y), float(x))))
        vt, vp = ang(vx, vy, vz)
        lt, lp = ang(lx, ly, lz)
        rows.append({"file": f, "view_theta": vt, "view_phi": vp, "light_theta": lt, "light_phi": lp})
    (tmp_path / "stack" / "dirs.json").write_text(json.dumps({"images": rows}))
    j = io.load(tmp_path / "stack", directions=tmp_path / "stack" / "dirs.json")
    np.testing.assert_array_equal(j.data, ref.data)
    np.testing.assert_allclose(j.lights, ref.lights, atol=1e-9)


def test_stack_bad_input(tmp_path):
    ref = btfrs.materials.make("bumps", size=8, seed=2).select(views=[0], lights=[0, 3])
    table = io.save_stack(ref, tmp_path / "s")
    Path(table).write_text(Path(table).read_text().replace("v000_l0001.exr", "v000_l9999.exr"))
    with pytest.raises(FormatError, match=r"v000_l9999\.exr.*does not exist"):
        io.load(tmp_path / "s", directions=table)
    # (a NaN inside an EXR is refused by the decoder, naming the file and pixel: Rust test
    # decode::tests::garbage_and_non_finite_exr_are_named_errors; our own writer cannot make one)
    img = np.zeros((8, 8, 3), np.float32)
    img[2, 3, 1] = np.nan
    with pytest.raises(InvalidArgumentError, match="not finite"):
        io.save_image(tmp_path / "n.exr", img)
    (tmp_path / "bad.csv").write_text("file,foo\na.png,1\n")
    with pytest.raises(FormatError, match="light direction"):
        io.load(tmp_path, directions=tmp_path / "bad.csv")


# --- streaming to disk --------------------------------------------------------------------------

def test_mmap_to_writes_the_same_btf_and_nothing_on_interrupt(tmp_path):
    write_ubo(tmp_path / "a")
    mem = io.load(tmp_path / "a")
    out = tmp_path / "big.btfrs"
    disk = io.load(tmp_path / "a", mmap_to=out, crop=(0, 0, H, W))
    assert isinstance(disk.data, np.ndarray) and not disk.data.flags.owndata
    np.testing.assert_array_equal(np.asarray(disk.data), mem.data)
    assert btfrs.load(out).shape == mem.shape

    # (an interrupted load leaves neither the target nor a temporary file: the Rust test
    # stack::tests::cancelled_stream_leaves_nothing, deterministic where a Ctrl-C is not)


def photographs(folder, fmt="png", n=10):
    """An RTI capture of ``n`` photographs of the relief (the first lights of RTI_LIGHTS, cycled)
    and its ``.lp``; returns the .lp's path and each photograph's pixels as PIL decodes them."""
    os.makedirs(folder, exist_ok=True)
    lines, pixels = [str(n)], []
    for i in range(n):
        l = RTI_LIGHTS[i % len(RTI_LIGHTS)]
        name = f"p{i:02d}.{fmt}"
        Image.fromarray(to_srgb8(shade(l))).save(os.path.join(folder, name), quality=95, subsampling=0)
        pixels.append(np.asarray(Image.open(os.path.join(folder, name)).convert("RGB")))
        lines.append(f"{name} {l[0]:.9f} {l[1]:.9f} {l[2]:.9f}")
    Path(folder, "dirs.lp").write_text("\n".join(lines) + "\n")
    return os.path.join(folder, "dirs.lp"), pixels


def test_photographs_held_or_spilled_under_memory_limit_load_as_decoded(tmp_path):
    # Ten 12 x 16 PNGs (576 bytes of samples each): with no limit all wait in memory; 10000 bytes
    # keep a few and spill the rest to the temporary file; 800 bytes (the least is 768: a third
    # more than one photograph) spill every one and write the capture a row at a time. Each load,
    # whole or cropped, in memory or to a memory-mapped file, must hold the values PIL decodes,
    # turned linear by the sRGB formula in float64, at the texel each pixel belongs to.
    lp, pixels = photographs(tmp_path / "cap")
    want = np.stack([srgb8_to_linear(p) for p in pixels], axis=2)[:, :, None]  # [H, W, 1, 10, 3]
    for crop in (None, (3, 5, 7, 9)):
        ref = want if crop is None else want[crop[0]:crop[0] + crop[2], crop[1]:crop[1] + crop[3]]
        for k, limit in enumerate((None, 10000, "800B", 800)):
            seen = []
            b = io.load(lp, crop=crop, memory_limit=limit, progress=lambda d, t: seen.append((d, t)))
            np.testing.assert_allclose(b.data, ref, atol=2e-7, err_msg=f"crop {crop}, memory_limit {limit}")
            # progress counts each photograph decoded and each written: 20 steps, ending at 20
            assert seen[-1] == (20, 20) and all(t == 20 for _, t in seen), seen
            out = tmp_path / f"m{k}{crop is None}.btfrs"
            m = io.load(lp, crop=crop, memory_limit=limit, mmap_to=out)
            np.testing.assert_array_equal(np.asarray(m.data), b.data)
    # JPEG: the streamed load equals the in-memory one bit for bit, and PIL's decode (libjpeg)
    # within two 8-bit steps, most values exactly (the decoders' inverse DCTs round differently)
    lp, pixels = photographs(tmp_path / "jpg", fmt="jpg")
    whole = io.load(lp)
    spilled = io.load(lp, memory_limit=800)
    np.testing.assert_array_equal(spilled.data, whole.data)
    srgb = np.stack(pixels, axis=2)[:, :, None].astype(np.float64)
    got = np.where(whole.data <= 0.0031308, 12.92 * whole.data, 1.055 * np.power(whole.data, 1 / 2.4) - 0.055) * 255
    err = np.abs(got - srgb)
    assert err.max() <= 2.01 and (err > 0.01).mean() < 0.2, (err.max(), (err > 0.01).mean())


def test_memory_limit_too_small_or_on_a_btfrs_file_is_a_clear_error(tmp_path):
    lp, _ = photographs(tmp_path / "cap")
    with pytest.raises(InvalidArgumentError, match=r"^memory_limit: expected at least 768 bytes to decode 16 x 12 "
                                                   r"photographs \(576 bytes of samples each\).*got 767$"):
        io.load(lp, memory_limit=767)
    with pytest.raises(InvalidArgumentError, match="memory_limit"):
        io.load(lp, memory_limit="lots")
    out = tmp_path / "b.btfrs"
    io.load(lp).save(out)
    with pytest.raises(InvalidArgumentError, match=r"memory_limit: only apply to measured captures"):
        io.load(out, memory_limit="1GB")


@pytest.mark.parametrize("spill", [None, 800])
def test_a_bad_photograph_names_the_file_and_writes_nothing(tmp_path, spill):
    # A photograph of another size, then a JPEG cut short: each refused naming the file, whether
    # the photographs wait in memory or in the temporary file, and no mmap_to file is left.
    lp, _ = photographs(tmp_path / "cap", fmt="jpg")
    good = Path(tmp_path / "cap" / "p06.jpg").read_bytes()
    Image.fromarray(to_srgb8(shade(RTI_LIGHTS[6]))[:, :15]).save(tmp_path / "cap" / "p06.jpg", quality=95)
    out = tmp_path / "out.btfrs"
    with pytest.raises(FormatError, match=r"p06\.jpg.*the image is 12 x 15 pixels; expected 12 x 16 like the first"):
        io.load(lp, memory_limit=spill, mmap_to=out)
    assert not out.exists()
    Path(tmp_path / "cap" / "p06.jpg").write_bytes(good[: len(good) * 2 // 3])
    with pytest.raises(FormatError, match=r"p06\.jpg.*truncated"):
        io.load(lp, memory_limit=spill, mmap_to=out)
    assert not out.exists() and os.listdir(tmp_path) == ["cap"]
    # the first photograph (whose header fixes the size) cut short: named too
    Path(tmp_path / "cap" / "p06.jpg").write_bytes(good)
    first = Path(tmp_path / "cap" / "p00.jpg")
    first.write_bytes(first.read_bytes()[:300])
    with pytest.raises(FormatError, match=r"p00\.jpg"):
        io.load(lp, memory_limit=spill)


# --- UBO2014 .btf (DFMF), written here byte by byte from the published layout -------------------

def write_dfmf(path, views, lights_deg, width, height, U, SV, cosine_flag=None, scale=(1, 1, 1)):
    """A `!DFMF08FCR` file: RGB colour model, float32 scalars; metadata version 1 without a
    cosine flag, else version 2 with it. ``U[c]`` is [views * lights, k], ``SV[c]``
    [width * height, k] (pixel = row * width + col, top row first); angles in radians in the
    file."""
    b = bytearray(b"!DFMF08FCR")
    version = 1 if cosine_flag is None else 2
    meta = struct.pack("<I", version) + b"setup".ljust(80, b"\0") + b"sensor".ljust(80, b"\0") \
        + b"lamp".ljust(80, b"\0") + struct.pack("<f", 10.0) + struct.pack("<3f", *scale)
    if cosine_flag is not None:
        meta += struct.pack("<I", cosine_flag)
    b += struct.pack("<I", 4 + len(meta)) + meta
    b += struct.pack("<I", len(views))
    for t, p in views:
        b += struct.pack("<ff", math.radians(t), math.radians(p)) + struct.pack("<I", len(lights_deg))
        for lt, lp in lights_deg:
            b += struct.pack("<ff", math.radians(lt), math.radians(lp))
    b += struct.pack("<II", width, height)
    b += struct.pack("<I", 0)  # no rotations
    k = U[0].shape[1]
    b += struct.pack("<Ii", k, 0) + struct.pack("<3f", 0, 0, 0) + struct.pack("<9f", 1, 0, 0, 0, 1, 0, 0, 0, 1)
    for c in range(3):
        b += struct.pack("<B", 4) + struct.pack("<III", k, U[c].shape[0], SV[c].shape[0])
        b += np.ones(k, "<f4").tobytes() + U[c].astype("<f4").tobytes() + SV[c].astype("<f4").tobytes()
    Path(path).write_bytes(bytes(b))


def test_ubo2014_dfmf_decodes_to_the_low_rank_product(tmp_path):
    rng = np.random.default_rng(4)
    views = [(0, 0), (30, 45)]
    lights = [(0, 0), (40, 10), (40, 130), (70, 250)]
    w, h, k = 5, 3, 2
    U = [rng.normal(size=(len(views) * len(lights), k)) for _ in range(3)]
    SV = [rng.normal(size=(w * h, k)) for _ in range(3)]
    p = tmp_path / "carpet_W5xH3_L4xV2.btf"
    write_dfmf(p, views, lights, w, h, U, SV, cosine_flag=1)
    b = io.load(p)
    assert b.shape == (h, w, 2, 4, 3)
    np.testing.assert_allclose(b.views, [direction(*v) for v in views], atol=1e-6)
    np.testing.assert_allclose(b.lights, [direction(*l) for l in lights], atol=1e-6)
    full = [(U[c].astype(np.float32).astype(np.float64) @ SV[c].astype(np.float32).astype(np.float64).T)
            .reshape(2, 4, h, w).transpose(2, 3, 0, 1) for c in range(3)]
    for c in range(3):
        np.testing.assert_allclose(b.data[..., c], full[c], atol=1e-5)
    assert b.meta["values"]["cosine"].startswith("in the file") and b.meta["cosine_flag"] == 1
    # Without the cosine flag (version 1, or the flag 0) the values exclude the cosine: the
    # reader multiplies it in; the RGB scale factors are applied per channel.
    cos_l = np.cos(np.radians([t for t, _ in lights]))
    for flag, scale in ((None, (1, 1, 1)), (0, (2.0, 0.5, 1.5))):
        q = tmp_path / f"flag{flag}.btf"
        write_dfmf(q, views, lights, w, h, U, SV, cosine_flag=flag, scale=scale)
        d = io.load(q)
        assert d.meta["values"]["cosine"].startswith("multiplied in") and d.meta["values"]["scale_applied"] == list(scale)
        for c in range(3):
            np.testing.assert_allclose(d.data[..., c], full[c] * cos_l[None, None, None, :] * scale[c], atol=1e-5)
    write_dfmf(tmp_path / "zero.btf", views, lights, w, h, U, SV, cosine_flag=1, scale=(1, 0, 1))
    with pytest.raises(FormatError, match=r"zero\.btf.*RGB scale factors"):
        io.load(tmp_path / "zero.btf")
    part = io.load(p, crop=(1, 2, 2, 3), lights=[3, 0])
    np.testing.assert_allclose(part.data, b.data[1:3, 2:5][:, :, :, [3, 0]], atol=1e-6)
    # truncated: a clear error, no allocation
    raw = p.read_bytes()
    (tmp_path / "cut.btf").write_bytes(raw[: len(raw) - 7])
    with pytest.raises(FormatError, match=r"cut\.btf"):
        io.load(tmp_path / "cut.btf")
    (tmp_path / "pvf.btf").write_bytes(b"!PVF06FCR" + raw[10:])
    with pytest.raises(FormatError, match="PVF06FCR"):
        io.load(tmp_path / "pvf.btf")


# --- dispatch, coefficient maps -----------------------------------------------------------------

def test_load_dispatches_on_the_file_type(tmp_path):
    ref = btfrs.materials.make("bumps", size=8, seed=2)
    ref.save(tmp_path / "b.btfrs")
    assert io.capture_kind(tmp_path / "b.btfrs") == "btfrs"
    sub = io.load(tmp_path / "b.btfrs", views=[1, 2], lights=[0], crop=(1, 1, 4, 5))
    np.testing.assert_array_equal(sub.data, ref.data[1:5, 1:6][:, :, [1, 2]][:, :, :, [0]])
    m = btfrs.fit.ptm(ref)
    m.save(tmp_path / "m.btfrs")
    assert isinstance(io.load(tmp_path / "m.btfrs"), btfrs.Ptm)
    with pytest.raises(InvalidArgumentError, match="only apply"):
        io.load(tmp_path / "m.btfrs", crop=(0, 0, 2, 2))
    one = io.load(write_lp(tmp_path / "cap"))
    h = btfrs.fit.hsh(one, order=2)
    h.save_rti(tmp_path / "h.rti")
    back = io.load(tmp_path / "h.rti")
    assert isinstance(back, btfrs.Hsh) and io.capture_kind(tmp_path / "h.rti") == "model_file"
    np.testing.assert_allclose(back.evaluate([0, 0, 1], RTI_LIGHTS[3]), h.evaluate([0, 0, 1], RTI_LIGHTS[3]), atol=1e-5)
    p = btfrs.fit.ptm(one)
    p.save_ptm(tmp_path / "p.ptm")
    assert isinstance(io.load(tmp_path / "p.ptm"), btfrs.Ptm)
    (tmp_path / "x.foo").write_text("hello")
    with pytest.raises(FormatError, match="unknown file type"):
        io.load(tmp_path / "x.foo")
    with pytest.raises(FileNotFoundError):
        io.load(tmp_path / "nope.zip")


def test_coefficient_planes_name_every_per_texel_value(tmp_path):
    ref = btfrs.materials.make("bumps", size=8, seed=2)
    for kind in btfrs.models.model_kinds():
        m = btfrs.fit.fit(kind, ref)
        names, planes = io.coefficient_planes(m)
        assert planes.shape == (len(names), 8, 8) and planes.dtype == np.float32
        assert len(set(names)) == len(names) and all(n.startswith(kind + ".") for n in names)
        # every texel array accounted for, value for value
        total = sum(int(np.prod(a.shape[2:])) for n, a in m.arrays.items()
                    if n in btfrs._native.texel_arrays(kind) and a.ndim >= 2 and a.shape[:2] == (8, 8))
        assert len(names) == total
        first = btfrs._native.texel_arrays(kind)[0]
        a = m.arrays.get(first)
        if a is not None and a.shape[:2] == (8, 8):
            np.testing.assert_array_equal(planes[0], np.asarray(a, np.float32).reshape(8, 8, -1)[:, :, 0])
        out = tmp_path / f"{kind}.exr"
        assert io.save_coefficients(m, out) == names and out.stat().st_size > 0
