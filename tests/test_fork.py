"""btfrs in child processes: ``fork`` (Linux's default start method before Python 3.14, also what
many data loaders use) and ``spawn``.

After a btfrs call the parent has a thread pool and a GPU device; a forked child inherits neither
the pool's threads nor the device's driver state, so btfrs must make its own in the child (it
used to hang there forever). Every wait on a child has a timeout, so a hang fails the test
instead of hanging the suite.
"""

import multiprocessing as mp
import os

import numpy as np
import pytest

import btfrs

METHODS = [m for m in ("fork", "spawn") if m in mp.get_all_start_methods()]
# Generous: a spawned child imports numpy and btfrs and opens lavapipe on a loaded 2-core machine.
TIMEOUT = 60
# Python 3.12+ warns when forking a process that has threads (btfrs's pool); that is the case
# under test.
pytestmark = pytest.mark.filterwarnings("ignore:.*multi-threaded.*fork.*:DeprecationWarning")


def work(seed: int):
    """Material, PTM fit and a GPU render; returns numbers both processes can compare."""
    btf = btfrs.materials.make("knit", size=16, seed=seed)
    ptm = btfrs.fit.ptm(btf)
    img = render(ptm)
    return ptm.error(btf).rmse, float(img.astype(np.float64).sum()), os.getpid()


def render(model):
    cam = btfrs.Camera.look_at(eye=[0, -2, 2], target=[0, 0, 0])
    return btfrs.render(model, btfrs.Scene.plane(), cam, btfrs.PointLight(position=[1, -1, 2], intensity=4.0), size=24)


def close(a, b):
    # Parallel reductions may sum in another order in another process.
    np.testing.assert_allclose(a, b, rtol=1e-5)


@pytest.mark.parametrize("method", METHODS)
def test_a_child_process_fits_and_renders_after_the_parent_did(method):
    rmse, total, me = work(3)  # the parent now has a thread pool and a device
    assert total > 0
    with mp.get_context(method).Pool(2) as pool:
        try:
            results = pool.map_async(work, [3, 3]).get(timeout=TIMEOUT)
        except mp.TimeoutError:
            pool.terminate()
            pytest.fail(f"a {method} child did not finish a fit and a render in {TIMEOUT} s (hung)")
    for r, t, pid in results:
        assert pid != me
        close(r, rmse)
        close(t, total)


def in_forked_child(target, *args):
    """Run ``target(*args, conn)`` in a forked child and return what it sends, failing on a hang."""
    ctx = mp.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)
    p = ctx.Process(target=target, args=(*args, send))
    p.start()
    send.close()
    try:
        assert recv.poll(TIMEOUT), f"the forked child did not answer in {TIMEOUT} s (hung)"
        got = recv.recv()
    finally:
        p.join(5)
        if p.is_alive():
            p.kill()
            p.join()
    assert p.exitcode == 0
    return got


def child_renders(model, conn):
    conn.send(float(render(model).astype(np.float64).sum()))


@pytest.mark.skipif("fork" not in METHODS, reason="no fork on this platform")
def test_a_forked_child_renders_a_model_the_parent_uploaded():
    # The parent's upload of this very object lives on the parent's device.
    ptm = btfrs.fit.ptm(btfrs.materials.make("weave", size=16, seed=4))
    want = float(render(ptm).astype(np.float64).sum())
    close(in_forked_child(child_renders, ptm), want)


def child_forks_again(conn):
    mine = work(5)
    with mp.get_context("fork").Pool(1) as pool:
        conn.send((mine, pool.apply_async(work, (5,)).get(timeout=TIMEOUT / 2)))


@pytest.mark.skipif("fork" not in METHODS, reason="no fork on this platform")
def test_a_forked_child_that_used_btfrs_can_fork_again():
    rmse, total, _ = work(5)
    for r, t, _ in in_forked_child(child_forks_again):
        close(r, rmse)
        close(t, total)
