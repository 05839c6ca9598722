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
