"""HSH (hemispherical harmonics) per view slot, .rti HSH files, and PTM's 8-bit planes."""

import struct

import numpy as np
import pytest

import btfrs
from btfrs.exceptions import ArgumentTypeError, DegenerateDataError, FormatError, InvalidArgumentError

D = btfrs.directions.ubo81()


def hsh_basis(order, l):
    """The RTI viewers' HSH basis in float64 numpy (an independent copy of the closed forms)."""
    l = np.atleast_2d(l)
    x = np.clip(l[:, 2], 0, 1)
    phi = np.arctan2(l[:, 1], l[:, 0])
    s = np.sqrt(np.maximum(x - x * x, 0))
    y = 2 * x - 1
    pi = np.pi
    b = [np.full_like(x, 1 / np.sqrt(2 * pi)),
         np.sqrt(6 / pi) * s * np.cos(phi), np.sqrt(3 / (2 * pi)) * y, np.sqrt(6 / pi) * s * np.sin(phi),
         np.sqrt(30 / pi) * (x * x - x) * np.cos(2 * phi), np.sqrt(30 / pi) * y * s * np.cos(phi),
         np.sqrt(5 / (2 * pi)) * (6 * x * x - 6 * x + 1), np.sqrt(30 / pi) * y * s * np.sin(phi),
         np.sqrt(30 / pi) * (x * x - x) * np.sin(2 * phi),
         2 * np.sqrt(35 / pi) * s ** 3 * np.cos(3 * phi), np.sqrt(210 / pi) * y * (x * x - x) * np.cos(2 * phi),
         2 * np.sqrt(21 / pi) * s * (5 * x * x - 5 * x + 1) * np.cos(phi),
         np.sqrt(7 / (2 * pi)) * (20 * x ** 3 - 30 * x * x + 12 * x - 1),
         2 * np.sqrt(21 / pi) * s * (5 * x * x - 5 * x + 1) * np.sin(phi),
         np.sqrt(210 / pi) * y * (x * x - x) * np.sin(2 * phi), 2 * np.sqrt(35 / pi) * s ** 3 * np.sin(3 * phi)]
    return np.stack(b[: order * order], axis=-1)


def numpy_hsh(btf, order):
    """Plain float64 least squares per view slot (numpy.linalg.lstsq)."""
    h, w, v, nl, _ = btf.shape
    out = np.zeros((h, w, v, 3, order * order))
    for vi in range(v):
        a = hsh_basis(order, btf.lights)
        sol = np.linalg.lstsq(a, btf.data[:, :, vi].astype(np.float64).reshape(h * w, nl, 3).transpose(1, 0, 2)
                              .reshape(nl, -1), rcond=None)[0]  # [n2, h*w*3]
        out[:, :, vi] = sol.reshape(order * order, h, w, 3).transpose(1, 2, 3, 0)
    return out


@pytest.fixture(scope="module")
def single_view():
    """A single-view capture of the built-in knit (the normal view), as an RTI dome sees it."""
    return btfrs.materials.make("knit", size=24, seed=3).select(views=[0])


def test_data_generated_by_an_hsh_are_recovered():
    rng = np.random.default_rng(0)
    coef = rng.uniform(-0.3, 0.6, size=(3, 4, 2, 3, 16))
    for order in (1, 2, 3, 4):
        c = coef[..., : order * order]
        data = np.einsum("hwvcj,lj->hwvlc", c, hsh_basis(order, D)).astype(np.float32)
        b = btfrs.Btf(data, D[:2], D)
        exact = btfrs.fit.hsh(b, order=order, bits=32, lambda_=0.0)
        assert isinstance(exact, btfrs.Hsh) and exact.order == order and exact.bits == 32
        np.testing.assert_allclose(exact.coeffs, c, atol=1e-4)
        q = btfrs.fit.hsh(b, order=order)
        assert q.bits == 8
        a = q.arrays
        step = a["coeffs_scale"].reshape(a["coeffs_q"].shape[2:])
        assert np.all(np.abs(q.coeffs - c) <= step / 2 + 1e-4)
        assert q.error(b).relative < 0.02
        # evaluation is the basis times the coefficients (float64 numpy reference)
        img = q.evaluate(D[1], D[30])
        np.testing.assert_allclose(img, np.einsum("hwcj,j->hwc", q.coeffs[:, :, 1], hsh_basis(order, D[30])[0]),
                                   atol=1e-5)


def test_agrees_with_float64_numpy_on_a_single_view_capture(single_view):
    ours = btfrs.fit.hsh(single_view, order=3, bits=32, lambda_=0.0).coeffs
    ref = numpy_hsh(single_view, 3)
    assert np.max(np.abs(ours - ref)) / np.max(np.abs(ref)) < 1e-5


def test_held_out_error_and_nbytes_by_order(single_view):
    train, test = single_view.split(holdout=0.2, seed=0)
    h, w = single_view.height, single_view.width
    errs = {}
    for order in (2, 3, 4):
        m = btfrs.fit.hsh(train, order=order)
        n2 = order * order
        k = 3 * n2
        assert m.nbytes == -(-(h * w * k) // 4) * 4 + 8 * k  # 1 byte per coefficient + scale and bias per plane
        errs[order] = m.error(test).relative
        assert m.error(train).relative <= errs[order] * 1.1
        f = btfrs.fit.hsh(train, order=order, bits=32)
        assert f.nbytes == 4 * h * w * k
        # 8-bit costs little accuracy
        assert abs(m.error(test).relative - f.error(test).relative) < 0.01
    assert 0.005 < errs[4] < 0.5 and errs[3] < errs[2] * 1.05, errs


def test_rti_round_trip(tmp_path, single_view):
    m = btfrs.fit.hsh(single_view, order=3)
    p = tmp_path / "knit.rti"
    scale, bias = m.save_rti(p)
    raw = p.read_bytes()
    lines = raw.split(b"\n", 4)
    assert lines[:4] == [b"#HSH1.2", b"3", b"24 24 3", b"9 2 1"]
    body = lines[4]
    assert len(body) == 8 * 9 + 24 * 24 * 3 * 9
    np.testing.assert_array_equal(np.frombuffer(body[:36], "<f4"), np.float32(scale))
    np.testing.assert_array_equal(np.frombuffer(body[36:72], "<f4"), np.float32(bias))
    back = btfrs.load(p)
    assert isinstance(back, btfrs.Hsh) and back.order == 3 and len(back.views) == 1
    np.testing.assert_array_equal(back.views, [[0, 0, 1]])
    np.testing.assert_array_equal(back.coeffs, m.coeffs)  # the planes come back bit for bit
    np.testing.assert_array_equal(back.arrays["coeffs_q"], m.arrays["coeffs_q"])
    np.testing.assert_array_equal(back.evaluate([0, 0, 1], D[20]), m.evaluate(D[0], D[20]))
    # relight's reading of the bytes, in numpy: bias + scale * c / 255, rows top to bottom
    q = np.frombuffer(body[72:], np.uint8).reshape(24, 24, 3, 9)
    dec = np.float32(bias) + np.float32(scale) * q / np.float32(255)
    np.testing.assert_allclose(dec, m.coeffs[:, :, 0], atol=1e-6)
    # written again: the same bytes
    back.save_rti(tmp_path / "again.rti")
    assert (tmp_path / "again.rti").read_bytes() == raw


def test_rti_of_a_float_model_and_errors(tmp_path, single_view):
    f = btfrs.fit.hsh(single_view, order=2, bits=32)
    f.save_rti(tmp_path / "f.rti")
    back = btfrs.load(tmp_path / "f.rti")
    step = back.arrays["coeffs_scale"].max()
    assert np.max(np.abs(back.coeffs[:, :, 0] - f.coeffs[:, :, 0])) <= step / 2 + 1e-6
    with pytest.raises(InvalidArgumentError, match="view"):
        f.save_rti(tmp_path / "x.rti", view=3)
    p = tmp_path / "ptm_type.rti"
    p.write_bytes(b"#HSH1.2\n1\n2 2 3\n")
    with pytest.raises(FormatError, match=r"ptm_type\.rti.*RTI type 1"):
        btfrs.load(p)
    p.write_bytes(b"#HSH1.2\n3\n2 2 3\n9 2 1\n" + b"\0" * 10)
    with pytest.raises(FormatError, match="truncated"):
        btfrs.load(p)
    p.write_bytes(b"PTM_1.2\n")
    with pytest.raises(FormatError, match="not an HSH"):
        btfrs.load(p)
    with pytest.raises(FileNotFoundError):
        btfrs.load(tmp_path / "missing.rti")
    ptm = btfrs.fit.ptm(single_view)
    with pytest.raises(InvalidArgumentError, match="format: the ptm model cannot be written as 'rti'"):
        ptm.export(tmp_path / "y.rti")
    with pytest.raises(InvalidArgumentError, match="format: the ptm model cannot be written as \"rti\""):
        btfrs._native.export_model(str(tmp_path / "y.rti"), ptm._m, "rti", 0)


def test_hand_made_rti_file(tmp_path):
    head = b"#HSH1.2\r\n# comment\n3\n2 1 3\n4 2 1\n"
    scale = [1.0, 2.0, 0.5, 0.25]
    bias = [0.0, -1.0, 0.125, 3.0]
    data = bytes(range(24))  # bottom row = the only row
    p = tmp_path / "hand.rti"
    p.write_bytes(head + struct.pack("<4f", *scale) + struct.pack("<4f", *bias) + data)
    m = btfrs.load(p)
    assert m.order == 2 and (m.height, m.width) == (1, 2)
    q = np.arange(24).reshape(1, 2, 3, 4)
    np.testing.assert_allclose(m.coeffs[:, :, 0], np.float32(bias) + np.float32(scale) / 255 * q, atol=1e-6)


def test_options_and_degenerate_slots(single_view):
    with pytest.raises(InvalidArgumentError, match="order"):
        btfrs.fit.hsh(single_view, order=5)
    with pytest.raises(ArgumentTypeError, match="order"):
        btfrs.fit.hsh(single_view, order=2.0)
    with pytest.raises(InvalidArgumentError, match="bits"):
        btfrs.fit.hsh(single_view, bits=16)
    with pytest.raises(InvalidArgumentError, match="lambda_"):
        btfrs.fit.hsh(single_view, lambda_=-1.0)
    with pytest.raises(InvalidArgumentError, match="ordr"):
        btfrs.fit.fit("hsh", single_view, ordr=2)
    few = single_view.select(lights=[0, 10, 20, 40, 60])
    with pytest.raises(DegenerateDataError, match="has 5 lights; an order-3 HSH needs at least 9"):
        btfrs.fit.hsh(few, on_degenerate="raise")
    m = btfrs.fit.hsh(few)  # reduced to a lower order, reported
    (slot,) = m.report["degenerate_slots"]
    assert slot["slot"] == 0 and slot["reason"] == "few lights" and slot["action"].startswith("order ")
    assert np.all(np.isfinite(m.coeffs))


def test_save_load_and_model_registry(tmp_path, single_view):
    m = btfrs.fit.hsh(single_view, order=2)
    m.save(tmp_path / "m.btfrs")
    back = btfrs.load(tmp_path / "m.btfrs")
    assert isinstance(back, btfrs.Hsh) and back.nbytes == m.nbytes
    np.testing.assert_array_equal(back.coeffs, m.coeffs)
    assert "hsh" in btfrs.models.model_kinds()
    assert "Hsh(order 2" in repr(m)


def test_ptm_is_8_bit_and_written_byte_for_byte(tmp_path, single_view):
    h, w = single_view.height, single_view.width
    for kind, per in (("rgb", 18), ("lrgb", 6)):
        q = btfrs.fit.ptm(single_view, kind=kind)
        f = btfrs.fit.ptm(single_view, kind=kind, bits=32)
        assert q.bits == 8 and f.bits == 32
        extra = (h * w * 3 + 8 * 3) if kind == "lrgb" else 0
        assert q.nbytes == h * w * per + 8 * per + extra
        assert f.nbytes == 4 * h * w * (per + (3 if kind == "lrgb" else 0))
        # within half a step of the float fit
        step = q.arrays["coeffs_scale"].reshape(q.arrays["coeffs_q"].shape[2:])
        assert np.all(np.abs(q.coeffs - f.coeffs) <= step / 2 + 1e-6)
        p = tmp_path / f"{kind}.ptm"
        q.save_ptm(p)
        back = btfrs.load(p)
        assert back.bits == 8 and back.nbytes == q.nbytes
        np.testing.assert_array_equal(back.arrays["coeffs_q"], q.arrays["coeffs_q"])  # the model's own bytes
        np.testing.assert_allclose(back.coeffs, q.coeffs, rtol=1e-6, atol=1e-7)
        back.save_ptm(tmp_path / "again.ptm")
        assert (tmp_path / "again.ptm").read_bytes() == p.read_bytes()
    with pytest.raises(InvalidArgumentError, match="bits"):
        btfrs.fit.ptm(single_view, bits=7)
