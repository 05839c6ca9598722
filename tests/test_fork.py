"""btfrs in child processes: ``fork`` (Linux's default start method before Python 3.14, also what
many data loaders use) and ``spawn``.

After a btfrs call the parent has a thread pool and a GPU device; a forked child inherits neither
the pool's threads nor the device's driver state, so btfrs must make its own in the child (it
used to hang there forever). Every wait on a child has a timeout, so a hang fails the test
instead of hanging the suite.
"""

import multiprocessing as mp
import os
import sys

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


RENDER_IN_A_FRESH_PROCESS = """
import os, stat, btfrs
d = os.environ.get("XDG_RUNTIME_DIR")
btf = btfrs.materials.make("knit", size=8, seed=1)
cam = btfrs.Camera.look_at(eye=[0, -2, 2], target=[0, 0, 0])
img = btfrs.render(btfrs.fit.ptm(btf), btfrs.Scene.plane(), cam, btfrs.PointLight(position=[1, -1, 2], intensity=4.0), size=8)
assert img.sum() > 0
mode = oct(stat.S_IMODE(os.stat(d).st_mode)) if d and os.path.isdir(d) else "-"
print(d, mode, btfrs.gpu_info())
"""


@pytest.mark.parametrize("value", [None, "", "/nonexistent/btfrs-test"])
def test_rendering_without_a_runtime_dir_is_quiet(value):
    # libwayland, probed by Mesa when a Vulkan device opens, prints "error: XDG_RUNTIME_DIR is
    # invalid or not set in the environment." when it is unset; btfrs gives the process a
    # private one (removed at exit) instead of needing scripts to set it.
    import subprocess

    env = {k: v for k, v in os.environ.items() if k != "XDG_RUNTIME_DIR"}
    if value is not None:
        env["XDG_RUNTIME_DIR"] = value
    r = subprocess.run([sys.executable, "-c", RENDER_IN_A_FRESH_PROCESS], env=env, capture_output=True, text=True,
                       timeout=TIMEOUT)
    assert "XDG_RUNTIME_DIR" not in r.stderr, r.stderr
    assert r.returncode == 0, r.stderr
    path, mode, _ = r.stdout.split(" ", 2)
    assert path not in ("None", "", value) and mode == "0o700"
    assert not os.path.exists(path), "the private runtime directory outlived its process"


def test_an_existing_runtime_dir_is_kept(tmp_path):
    import subprocess

    env = dict(os.environ, XDG_RUNTIME_DIR=str(tmp_path))
    tmp_path.chmod(0o700)
    r = subprocess.run([sys.executable, "-c", RENDER_IN_A_FRESH_PROCESS], env=env, capture_output=True, text=True,
                       timeout=TIMEOUT)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split(" ")[0] == str(tmp_path) and tmp_path.exists()
