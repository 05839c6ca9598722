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
    with pytest.raises(ValueError, match="coeffs: expected shape"):
        btfrs.Ptm.from_arrays("rgb", np.zeros((2, 2, 2, 6), np.float32), d)
    bad = np.zeros((2, 2, 2, 3, 6), np.float32)
    bad[0, 0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="not finite"):
        btfrs.Ptm.from_arrays("rgb", bad, d)
    with pytest.raises(ValueError, match="rgb"):
        btfrs.Ptm.from_arrays("lrgb", np.zeros((2, 2, 2, 6), np.float32), d)


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
