import numpy as np
import pytest

import btfrs
from btfrs.exceptions import FormatError

D = btfrs.directions.ubo81()


def header_and_body(path):
    raw = path.read_bytes()
    pos = 0
    for _ in range(6):  # version, format, width, height, scales, biases
        pos = raw.index(b"\n", pos) + 1
    return raw[:pos].decode().split("\n")[:-1], raw[pos:]


@pytest.mark.parametrize("kind", ["rgb", "lrgb"])
def test_round_trip_within_the_8bit_bound(tmp_path, knit, kind):
    ptm = btfrs.fit.ptm(knit.select(views=[0, 12]), kind=kind)
    p = tmp_path / "a.ptm"
    scale, bias = ptm.save_ptm(p, view=1)
    head, _ = header_and_body(p)
    assert head[0] == "PTM_1.2" and head[1] == f"PTM_FORMAT_{kind.upper()}" and head[2:4] == ["32", "32"]
    back = btfrs.load(p)
    assert back.variant == kind and back.height == 32 and back.width == 32
    got = back.coeffs[:, :, 0]
    want = ptm.coeffs[:, :, 1]
    bound = np.asarray(scale) / 2 + 1e-6
    assert np.all(np.abs(got - want) <= bound)
    if kind == "lrgb":
        assert np.max(np.abs(back.rgb[:, :, 0] - ptm.rgb[:, :, 1])) <= 0.5 / 255 + 1e-6


@pytest.mark.parametrize("kind", ["rgb", "lrgb"])
def test_rows_are_stored_bottom_to_top(tmp_path, kind):
    # A 3 x 2 image whose constant term (and LRGB colour) depends on both row and column, so a
    # flip in either direction changes the bytes. Row 0 is the top of the image.
    a5 = np.array([[0.1, 0.2], [0.5, 0.6], [0.8, 0.9]], np.float32)
    if kind == "rgb":
        coeffs = np.zeros((3, 2, 1, 3, 6), np.float32)
        coeffs[..., 5] = a5[:, :, None, None]
        rgb = None
    else:
        coeffs = np.zeros((3, 2, 1, 6), np.float32)
        coeffs[..., 5] = a5[:, :, None]
        rgb = np.zeros((3, 2, 1, 3), np.float32)
        rgb[..., 0] = (a5 / 0.9)[:, :, None]
    coeffs[..., 3] = 0.05  # keep the other scales non-trivial
    arrays = {"coeffs": coeffs, "views": D[:1]}
    if rgb is not None:
        arrays["rgb"] = rgb
    ptm = btfrs.Ptm.from_arrays(arrays)
    p = tmp_path / "rows.ptm"
    ptm.save_ptm(p, view=0)
    _, body = header_and_body(p)
    # The first block (R for RGB, luminance for LRGB), 6 bytes per pixel, file row 0 = bottom.
    got = np.frombuffer(body[: 3 * 2 * 6], np.uint8).reshape(3, 2, 6)[:, :, 5].astype(int)
    order = np.argsort(got.ravel())
    np.testing.assert_array_equal(order, np.argsort(a5[::-1].ravel()))
    if kind == "lrgb":
        red = np.frombuffer(body[3 * 2 * 6 : 3 * 2 * 9], np.uint8).reshape(3, 2, 3)[:, :, 0]
        np.testing.assert_array_equal(red, np.round(255 * a5[::-1] / 0.9))
    back = btfrs.load(p)
    np.testing.assert_allclose(back.coeffs[:, :, 0, ..., 5].reshape(3, 2, -1)[:, :, 0], a5, atol=0.01)


def test_reads_a_file_written_by_another_tool(tmp_path):
    # Hand-written LRGB file: CRLF line ends and a trailing space, as other writers produce.
    scale = [2.0] * 6
    bias = [0, 0, 0, 0, 0, 10]
    head = "PTM_1.2\r\nPTM_FORMAT_LRGB\r\n2\r\n1 \r\n" + " ".join(map(str, scale)) + "\r\n" + " ".join(map(str, bias)) + "\r\n"
    coef = bytes([1, 2, 3, 4, 5, 60, 0, 0, 0, 0, 0, 110])
    rgb = bytes([255, 0, 0, 0, 255, 255])
    p = tmp_path / "other.ptm"
    p.write_bytes(head.encode() + coef + rgb)
    m = btfrs.load(p)
    # Decoded a_k = (byte - bias_k) * scale_k, in byte units; ours are /255.
    np.testing.assert_allclose(m.coeffs[0, 0, 0], np.array([1, 2, 3, 4, 5, 50]) * 2 / 255, rtol=1e-6)
    np.testing.assert_allclose(m.coeffs[0, 1, 0, 5], 100 * 2 / 255, rtol=1e-6)
    np.testing.assert_allclose(m.rgb[0, :, 0], [[1, 0, 0], [0, 1, 1]])
    img = m.evaluate([0, 0, 1], [0, 0, 1])  # lu = lv = 0: only a5 counts
    np.testing.assert_allclose(img[0, 0], [100 / 255, 0, 0], rtol=1e-6)


def test_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError):
        btfrs.load(tmp_path / "nope.ptm")
    p = tmp_path / "jpeg.ptm"
    p.write_bytes(b"PTM_1.2\nPTM_FORMAT_JPEGLS_LRGB\n2\n2\n")
    with pytest.raises(FormatError, match="PTM_FORMAT_JPEGLS_LRGB.*not supported"):
        btfrs.load(p)
    p.write_bytes(b"PTM_1.2\nPTM_FORMAT_JPEG_LRGB\n2\n2\n1 1 1 1 1 1\n0 0 0 0 0 0\n90\n" + b"0 " * 40)
    with pytest.raises(FormatError, match="truncated.*reference plane of plane 4"):
        btfrs.load(p)
    p.write_bytes(b"PTM_1.2\nPTM_FORMAT_RGB\n2\n2\n1 1 1 1 1 1\n0 0 0 0 0 0\n" + bytes(10))
    with pytest.raises(FormatError):
        btfrs.load(p)
