"""Model files from strangers: finite but huge stored values never give a silent non-finite value.

A stored value may be finite and still overflow when the model is evaluated (a `.ptm` whose
scales are 3e38). Every way out of a model (evaluate, error, the CPU and the GPU renderer) either
returns finite values or raises `NumericalError` naming the model and the array holding the
largest value; a model may also be refused when it is read.
"""

from __future__ import annotations

import numpy as np
import pytest

import btfrs
from btfrs.exceptions import FormatError, InvalidArgumentError, NumericalError

KINDS = btfrs.model_kinds()


@pytest.fixture(scope="module")
def bumps():
    return btfrs.materials.make("bumps", size=8, seed=3)


def _outputs(m, btf):
    """Every way a model's values come out: (name, call)."""
    scene = btfrs.Scene.plane(2.0)
    cam = btfrs.Camera.look_at([0, -0.01, 3], [0, 0, 0], 40)
    lights = [btfrs.DirectionalLight([0.3, 0.2, 0.93], 1.0)]
    return [
        ("evaluate", lambda: m.evaluate([0, 0, 1], [0.3, 0.2, 0.93])),
        ("error", lambda: np.asarray([m.error(btf).rmse])),
        ("cpu render", lambda: btfrs.render(m, scene, cam, lights, size=16, backend="cpu")),
        ("gpu render", lambda: btfrs.render(m, scene, cam, lights, size=16)),
    ]


def _probe(kind, btf, folder):
    """Each float array of ``kind``'s first example replaced by huge values of its signs, read
    back through a file: counts of the arrays refused when read and of those read cleanly, and of
    the outputs of the latter that were finite or raised NumericalError (asserted as they come)."""
    _, options = KINDS[kind]["examples"][0]
    arrays = btfrs.fit.fit(kind, btf, **options).arrays
    n = dict(arrays=0, refused=0, read=0, finite=0, raised=0)
    for name, a in arrays.items():
        if a.dtype.kind != "f" or a.size == 0:
            continue
        n["arrays"] += 1
        huge = np.float32(3e38) if a.dtype == np.float32 else 1e300
        big = dict(arrays)
        big[name] = np.where(a < 0, -huge, huge).astype(a.dtype)
        try:
            m = btfrs.Model.from_arrays(big, kind=kind)
            m.save(folder / "m.btfrs")
            m = btfrs.load(folder / "m.btfrs")
        except (InvalidArgumentError, FormatError):
            n["refused"] += 1  # refused when read: fine
            continue
        n["read"] += 1
        for what, call in _outputs(m, btf):
            try:
                out = call()
            except NumericalError as e:
                msg = str(e)
                assert "non-finite" in msg and repr(name) in msg.replace('"', "'"), (what, name, msg)
                n["raised"] += 1
                continue
            assert np.all(np.isfinite(out)), (kind, name, what)
            n["finite"] += 1
    return n


# Each kind's counts, probed once per process (the test of the minima reuses them).
_COUNTS: dict = {}


def _counts(kind, btf, tmp_path_factory):
    if kind not in _COUNTS:
        _COUNTS[kind] = _probe(kind, btf, tmp_path_factory.mktemp(kind))
    return _COUNTS[kind]


@pytest.mark.parametrize("kind", list(KINDS))
def test_huge_stored_values_are_refused_or_raise_numerical_error(kind, bumps, tmp_path_factory):
    n = _counts(kind, bumps, tmp_path_factory)
    # Every float array was either refused or read, and every output of a read one checked.
    assert n["arrays"] >= 1, (kind, n)
    assert n["refused"] + n["read"] == n["arrays"], (kind, n)
    assert n["finite"] + n["raised"] == 4 * n["read"], (kind, n)


def test_the_probe_of_huge_values_reads_models_and_refuses_some(bumps, tmp_path_factory):
    # Over the whole registry, so that the test above cannot pass by refusing everything: most
    # arrays are read and their outputs checked (22 of 32 when this was written, at least one in
    # every kind but svbrdf, whose maps have bounded ranges), some are refused, and both ways out
    # of a read model (finite values, NumericalError) are taken.
    total = dict(arrays=0, refused=0, read=0, finite=0, raised=0)
    kinds_read = 0
    for kind in KINDS:
        n = _counts(kind, bumps, tmp_path_factory)
        kinds_read += n["read"] > 0
        for k in total:
            total[k] += n[k]
    assert total["read"] >= total["arrays"] // 2 and kinds_read >= len(KINDS) - 2, (total, kinds_read)
    assert total["refused"] >= 1 and total["finite"] >= 1 and total["raised"] >= 1, total


def test_a_ptm_file_with_huge_scales_raises_numerical_error_not_inf(tmp_path):
    # The .ptm of another tool: its six scales rewritten as 3e38 (finite floats), its biases 0.
    one = btfrs.materials.make("bumps", size=8, seed=3).select(views=[0])
    btfrs.fit.ptm(one).export(tmp_path / "a.ptm")
    raw = (tmp_path / "a.ptm").read_bytes()
    lines = raw.split(b"\n")
    # PTM_1.2, format, width, height, scales, biases, then the coefficient bytes.
    lines[4] = b" ".join([b"3e38"] * 6)
    lines[5] = b" ".join([b"0"] * 6)  # every coefficient in [0, 3e38]: their sum overflows
    (tmp_path / "huge.ptm").write_bytes(b"\n".join(lines))
    m = btfrs.load(tmp_path / "huge.ptm")  # every stored value is finite: it loads
    # At some of the 81 UBO lights the biquadratic overflows (11 of 81 in the reported file):
    # there it must raise, everywhere else give finite values.
    raised = 0
    for light in btfrs.directions.ubo81():
        try:
            out = m.evaluate([0, 0, 1], light)
        except NumericalError as e:
            assert "ptm model gives non-finite" in str(e) and "coeffs" in str(e), str(e)
            raised += 1
            continue
        assert np.all(np.isfinite(out))
    assert raised > 0


def test_a_raw_btf_with_huge_values_does_not_render_inf(tmp_path):
    btf = btfrs.materials.make("bumps", size=8, seed=3)
    data = np.array(btf.data)
    data[..., :] = 3e38
    big = btfrs.Btf(data, btf.views, btf.lights)
    scene = btfrs.Scene.plane(2.0)
    cam = btfrs.Camera.look_at([0, -0.01, 3], [0, 0, 0], 40)
    lights = [btfrs.DirectionalLight([0.3, 0.2, 0.93], 4.0)]
    for backend in ("cpu", "gpu"):
        with pytest.raises(NumericalError, match="raw BTF|'data'"):
            btfrs.render(big, scene, cam, lights, size=16, backend=backend)
