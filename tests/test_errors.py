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


_CTRL_C_CHILD = (
    "import json, signal, time, btfrs\n"
    "ticks = []\n"
    "def tick(d, t):\n"
    "    ticks.append((time.time(), d, t))\n"
    "    if len(ticks) == 1:\n"
    "        print('started', flush=True)\n"
    "outcome, returned, stopped = None, None, None\n"
    # The outer handler: a signal aimed at the very end of the work may arrive after the call
    # returned; it must not kill the report.
    "try:\n"
    "    try:\n"
    "        btfrs.materials.make('knit', size=128, progress=tick)\n"
    "        returned = time.time()\n"
    "        outcome = 'finished'\n"
    "    except KeyboardInterrupt:\n"
    "        stopped = time.time()\n"
    "        outcome = 'interrupted'\n"
    "    signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
    "except KeyboardInterrupt:\n"
    "    signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
    "print(json.dumps({'outcome': outcome, 'returned': returned, 'stopped': stopped, 'end': time.time(),\n"
    "                  'ticks': ticks}), flush=True)\n"
)


def _interrupt_after(delay: float) -> tuple:
    """Run the child, send it SIGINT ``delay`` seconds after its first progress tick: (its
    report, the time just before the signal was sent, the time just after). On a loaded machine
    this process can be descheduled between taking a time and sending the signal, so what the
    child may have done before the signal is judged against the time after."""
    import json
    import signal
    import subprocess
    import sys
    import time

    p = subprocess.Popen([sys.executable, "-c", _CTRL_C_CHILD], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout is not None and p.stdout.readline().strip() == "started"
        time.sleep(delay)
        t_before = time.time()
        p.send_signal(signal.SIGINT)
        t_after = time.time()
        out, _ = p.communicate(timeout=120)
    finally:
        p.kill()
    return json.loads(out), t_before, t_after


def test_ctrl_c_interrupts_long_work_promptly():
    # A real SIGINT while Rust generates a large material (GIL released): the call must raise
    # KeyboardInterrupt and stop well before the work would have finished. "Well before" is
    # measured, not fixed: the child's progress ticks give the rate this (possibly loaded)
    # machine achieves, hence how long the rest would have taken; stopping must take less than
    # half of that (it takes about 0.1 s: one poll of the waiting thread plus one chunk).
    #
    # The signal is sent at several moments, the last ones aimed at the end of the work, where
    # a signal noticed as the work completes could be dropped. A child whose work ended before
    # the signal was even sent (a loaded machine can delay this process that long) says nothing
    # either way; one that got the signal while working and finished normally lost it: a bug.
    #
    # The end is aimed at from the first run's ticks; when they show no progress (a machine so
    # loaded that the child advanced by less than a tick before the signal), there is no rate to
    # aim with and only the first moment is checked (a rate of 0 once made this test sleep for
    # ever).
    r, t_signal, t_sent = _interrupt_after(0.5)
    ticks = r["ticks"]
    span, advanced = ticks[-1][0] - ticks[0][0], ticks[-1][1] - ticks[0][1]
    moments = [0.5]
    if span > 0 and advanced > 0:
        whole = ticks[0][2] * span / advanced  # seconds the whole work takes here
        moments += [min(max(0.05, f * whole), 120.0) for f in (0.9, 0.97, 1.0)]
    interrupted = 0
    for k, delay in enumerate(moments):
        if k:
            r, t_signal, t_sent = _interrupt_after(delay)
        if r["outcome"] == "finished":
            assert r["returned"] <= t_sent + 0.05, (
                f"SIGINT sent {delay:.2f} s into the work at {t_signal:.3f}-{t_sent:.3f} was lost: the call "
                f"returned normally at {r['returned']:.3f}")
            continue
        interrupted += 1
        if k:
            continue  # aimed at the end: only "not lost" is checked (the rest is too short to time)
        before = [(t, d, n) for t, d, n in r["ticks"] if t <= t_signal]
        (t0, d0, total), (t1, d1, _) = before[0], before[-1]
        if d1 > d0:
            remaining = (total - d1) / ((d1 - d0) / (t1 - t0))
            latency = (r["stopped"] or r["end"]) - t_signal
            assert latency < max(0.5 * remaining, 0.3), (
                f"stopping took {latency:.2f} s; the rest of the work would have taken about {remaining:.1f} s"
            )
    assert interrupted >= 1, "the signal never came while the work ran: nothing was checked"


def test_a_rust_panic_is_an_internal_error():
    # A hidden native hook panics in each place a binding runs Rust code: with the GIL held
    # (guarded), with it released (detach), on the monitored worker, and on a rayon thread.
    for place in ["held", "detached", "monitored", "parallel"]:
        with pytest.raises(ex.InternalError, match=r"internal error in btfrs \(please report it\): test panic"):
            btfrs._native._panic_for_test(place)
    with pytest.raises(ex.InvalidArgumentError, match="place"):
        btfrs._native._panic_for_test("nowhere")
    # The thread pool survives a panic in one of its threads.
    st = np.random.default_rng(0).random((1000, 2))
    np.testing.assert_allclose(btfrs.hemimap.disk_to_square(btfrs.hemimap.square_to_disk(st)), st, atol=1e-12)


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
