import numpy as np
import pytest

import btfrs
from btfrs import exceptions as ex


def test_hierarchy():
    assert issubclass(ex.InvalidArgumentError, ex.BtfrsError) and issubclass(ex.InvalidArgumentError, ValueError)
    assert issubclass(ex.DegenerateDataError, ValueError) and issubclass(ex.FormatError, ValueError)
    assert issubclass(ex.InternalError, RuntimeError)


def test_wrong_types_are_type_errors(knit):
    with pytest.raises(TypeError, match="btf: expected a btfrs.Btf"):
        btfrs.fit.ptm(knit.data)
    with pytest.raises(TypeError, match="progress"):
        btfrs.fit.ptm(knit, progress="yes")
    ptm = btfrs.fit.ptm(knit.select(views=[0]))
    with pytest.raises(TypeError, match="btf"):
        ptm.error(np.zeros(3))


def test_a_failing_progress_callback_cancels_the_work():
    calls = []

    def stop(done, total):
        calls.append(done)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        btfrs.materials.make("knit", size=96, progress=stop)
    assert len(calls) == 1


def test_model_from_bad_arrays():
    d = btfrs.directions.ubo81()[:2]
    with pytest.raises(btfrs.InvalidArgumentError, match="coeffs: expected shape"):
        btfrs.Ptm.from_arrays({"coeffs": np.zeros((2, 2, 3, 6), np.float32), "views": d})
    bad = np.zeros((2, 2, 2, 3, 6), np.float32)
    bad[0, 0, 0, 0, 0] = np.nan
    with pytest.raises(btfrs.InvalidArgumentError, match="not finite"):
        btfrs.Ptm.from_arrays({"coeffs": bad, "views": d})
    with pytest.raises(btfrs.InvalidArgumentError, match="rgb: missing"):
        btfrs.Ptm.from_arrays({"coeffs": np.zeros((2, 2, 2, 6), np.float32), "views": d})
    with pytest.raises(btfrs.InvalidArgumentError, match="kind: Ptm holds 'ptm' models"):
        btfrs.Ptm.from_arrays({}, kind="lpca")
    with pytest.raises(btfrs.InvalidArgumentError, match="kind: expected the model's name"):
        btfrs.Model.from_arrays({})
    with pytest.raises(btfrs.InvalidArgumentError, match="views: expected dtype f64, got f32"):
        btfrs.Ptm.from_arrays({"coeffs": bad, "views": d.astype(np.float32)})


def test_ctrl_c_interrupts_long_work_promptly():
    # A real SIGINT while Rust generates a large material (GIL released): the call must stop
    # within a fraction of the full run time and raise KeyboardInterrupt.
    import signal
    import subprocess
    import sys
    import time

    code = (
        "import sys, btfrs\n"
        "def tick(d, t):\n"
        "    print('started', flush=True)\n"
        "try:\n"
        "    btfrs.materials.make('knit', size=256, progress=tick)\n"
        "    print('finished', flush=True)\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted', flush=True)\n"
    )
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "started"
    t0 = time.perf_counter()
    p.send_signal(signal.SIGINT)
    out, _ = p.communicate(timeout=30)
    assert "interrupted" in out and "finished" not in out
    assert time.perf_counter() - t0 < 2.0


def test_argument_checks_in_the_python_layer(knit):
    with pytest.raises(ValueError, match="kind"):
        btfrs.fit.ptm(knit, kind=None)
    with pytest.raises(ValueError, match="seed"):
        knit.split(holdout=0.1, seed=-1)
    with pytest.raises(TypeError, match="seed"):
        btfrs.materials.make("knit", size=16, seed=1.7)
    with pytest.raises(ValueError, match=r"st: expected shape"):
        btfrs.hemimap.square_to_hemisphere(0.5)
    with pytest.raises(TypeError, match="real numbers"):
        btfrs.hemimap.square_to_disk(np.array([0.5 + 1j, 0.5]))
    ptm = btfrs.fit.ptm(knit.select(views=[0, 1]))
    with pytest.raises(TypeError, match="bool"):
        ptm.slot(True)


def test_masks_from_raw_bytes_are_normalised():
    d = btfrs.directions.ubo81()
    raw = np.full((81, 81), 2, np.uint8)  # numpy reads every byte as True
    raw[0, 0] = 0
    b = btfrs.Btf(np.ones((1, 1, 81, 81, 3), np.float32), d, d, mask=raw.view(bool))
    assert b.pairs == 81 * 81 - 1
    train, test = b.split(holdout=0.1, seed=0)
    assert train.pairs + test.pairs == 81 * 81 - 1


def test_unchecked_samples_still_check_directions_and_shapes():
    d = btfrs.directions.ubo81()
    with pytest.raises(ValueError, match="views"):
        btfrs.Btf(np.ones((1, 1, 81, 81, 3), np.float32), d * 2, d, check=False)
    with pytest.raises(ValueError, match="non-empty"):
        btfrs.Btf(np.ones((0, 1, 81, 81, 3), np.float32), d, d, check=False)
    # check=False skips only the value scan.
    bad = np.ones((1, 1, 81, 81, 3), np.float32)
    bad[0, 0, 0, 0, 0] = np.nan
    assert btfrs.Btf(bad, d, d, check=False).data is bad
