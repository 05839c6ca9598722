"""Out-of-core fitting: every fit of a memory-mapped ``.btfrs`` under ``memory_limit``.

The bound is checked where it lives, in the operating system's count: each fit runs in a fresh
subprocess that samples its anonymous resident memory (``RssAnon`` in ``/proc/self/status``; the
mapped file's pages are file-backed and not in it, while ``VmHWM`` would count them) during the
fit, and the growth must stay below the limit plus the model it returns.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import btfrs
from btfrs._checks import memory_size
from btfrs.exceptions import ArgumentTypeError, FormatError, InvalidArgumentError
from btfrs.tools.bench import light_basis_steps

LIMIT = "64MB"

KINDS = btfrs.model_kinds()
# Each registered model at the cheapest setting that runs every stage of its fit (its registry
# entry says which).
OPTIONS = {kind: info["smallest"] for kind, info in KINDS.items()}


@pytest.fixture(scope="module")
def big(tmp_path_factory):
    """A ~200 MB BTF on disk (72 x 72 texels, 81 views x 41 lights), as a memory-mapped Btf."""
    path = tmp_path_factory.mktemp("ooc") / "big.btfrs"
    v = btfrs.directions.ubo81()
    btfrs.materials.make("bumps", size=72, views=v, lights=v[::2], seed=3, out=path)  # streamed to disk
    return path


@pytest.mark.parametrize("kind", sorted(OPTIONS))
def test_every_fit_of_a_mapped_btf_stays_within_its_memory_limit(big, kind):
    opts = dict(OPTIONS[kind], memory_limit=LIMIT)
    # A fresh interpreter per fit (btfrs.tools.memprobe says what it measures and how).
    r = subprocess.run([sys.executable, "-m", "btfrs.tools.memprobe", str(big), kind, json.dumps(opts)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    m = json.loads(r.stdout.strip().splitlines()[-1])
    assert m["data"] > 190e6  # the data is three times the limit: it cannot have been copied
    assert m["growth"] <= memory_size("limit", LIMIT) + m["model"], (kind, m)


def test_the_analysis_of_a_mapped_btf_stays_within_its_memory_limit(big):
    # Its result (1024 textons, their distance table, the candidate lists) is not added: the
    # growth must stay below the limit alone. Without a limit the range finder's sample alone
    # copies 2048 texels of 40 kB (82 MB).
    r = subprocess.run([sys.executable, "-m", "btfrs.tools.memprobe", str(big), "analyse",
                        json.dumps({"textons": 1024, "memory_limit": LIMIT})],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    m = json.loads(r.stdout.strip().splitlines()[-1])
    assert m["growth"] <= memory_size("limit", LIMIT), m
    btf = btfrs.Btf.load(big, mmap=True)
    with pytest.raises(InvalidArgumentError, match=r"memory_limit: expected at least [\d.]+ MB for the analysis"):
        btfrs.synth.analyse(btf, textons=64, memory_limit="8MB")
    with pytest.raises(InvalidArgumentError, match="memory_limit: applies to a Btf sample"):
        btfrs.synth.analyse(np.zeros((16, 16, 3), np.float32), memory_limit="1GB")


def test_lpca_under_a_limit_streams_and_stays_close_to_the_unlimited_fit(big):
    # A limit far below one cluster's values (each of the 4 clusters holds ~1300 texels of 40 kB)
    # streams the range finder's sample and the clusters' PCA in chunks of ~200 texels.
    # Randomized subspace iteration on a streamed cluster instead of its exact PCA, so equal
    # within a tolerance: the clustering (in principal coordinates) is the same, the
    # reconstruction error within 2 % of the unlimited fit's.
    btf = btfrs.Btf.load(big, mmap=True)
    free = btfrs.fit.lpca(btf, clusters=4, components=4)
    tight = btfrs.fit.lpca(btf, clusters=4, components=4, memory_limit="48MB")
    e_free, e_tight = free.error(btf).relative, tight.error(btf).relative
    assert abs(e_tight - e_free) <= 0.02 * e_free, (e_free, e_tight)
    agree = np.mean(free.arrays["ids"] == tight.arrays["ids"])
    assert agree > 0.95, agree


def test_a_limit_below_the_least_a_fit_needs_is_an_error_naming_it(big):
    btf = btfrs.Btf.load(big, mmap=True)
    with pytest.raises(InvalidArgumentError, match=r"memory_limit: expected at least [\d.]+ MB for an LPCA fit"):
        btfrs.fit.lpca(btf, clusters=4, memory_limit="2MB")
    with pytest.raises(InvalidArgumentError, match=r"memory_limit: expected at least 16.0 MB for a ptm fit"):
        btfrs.fit.ptm(btf, memory_limit=10**6)
    # Double SH holds its float coefficients before quantizing (4 x 3 x 256 per texel: 15.9 MB
    # here): its least grows with the texels. RBF's is every view slot's moments and a block.
    with pytest.raises(InvalidArgumentError, match=r"memory_limit: expected at least 31\.9 MB for a sh fit of 72 x 72"):
        btfrs.fit.sh(btf, light_coeffs=16, view_coeffs=16, memory_limit="20MB")
    with pytest.raises(InvalidArgumentError, match=r"memory_limit: expected at least [\d.]+ MB for a rbf fit"):
        btfrs.fit.rbf(btf, components=8, memory_limit="20MB")
    with pytest.raises(InvalidArgumentError, match="memory_limit: a fit under a memory limit clusters in principal"):
        btfrs.fit.lpca(btf, clusters=4, reduced_dims=0, memory_limit="1GB")


def test_rbf_below_its_coefficients_keeps_them_in_a_temporary_file(big):
    # 72^2 texels x 81 views x 8 planes of float coefficients are 13.4 MB; the fit's least (the
    # moments of every view slot's samples and a block) is 30.1 MB. Under 32 MB the coefficients
    # wait for the 8-bit quantization in an unlinked temporary file: the anonymous memory stays
    # within the limit, and the model is the unlimited fit's to rounding.
    opts = {"components": 8, "memory_limit": "32MB"}
    r = subprocess.run([sys.executable, "-m", "btfrs.tools.memprobe", str(big), "rbf", json.dumps(opts)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    m = json.loads(r.stdout.strip().splitlines()[-1])
    assert m["growth"] <= memory_size("limit", "32MB") + m["model"], m
    mapped = btfrs.Btf.load(big, mmap=True)
    tight = btfrs.fit.rbf(mapped, **opts)
    free = btfrs.fit.rbf(btfrs.Btf.load(big), components=8)
    assert light_basis_steps(tight, free) <= 1.01
    assert tight.error(mapped).rmse == pytest.approx(free.error(mapped).rmse, rel=1e-4)


def test_memory_sizes_are_parsed_as_dask_writes_them():
    assert memory_size("m", "64MB") == 64_000_000
    assert memory_size("m", "2GB") == 2_000_000_000
    assert memory_size("m", "1.5 GiB") == 3 * 2**29
    assert memory_size("m", "512mib") == 512 * 2**20
    assert memory_size("m", 12345) == 12345 and memory_size("m", None) is None
    for bad in ("2 parsecs", "", "-5MB", "MB"):
        with pytest.raises(InvalidArgumentError, match="m: expected a number of bytes"):
            memory_size("m", bad)
    with pytest.raises(InvalidArgumentError, match="positive"):
        memory_size("m", 0)
    with pytest.raises(ArgumentTypeError, match="m: expected a number of bytes"):
        memory_size("m", 2.5e9)


def test_a_material_written_to_a_file_equals_the_one_made_in_memory(tmp_path):
    # The blur (subsurface) runs in place row by row when streaming: the same values bit for bit.
    v = btfrs.directions.ubo81()[::4]
    for sub in (0.0, 0.3):
        mem = btfrs.materials.make("knit", size=24, views=v, lights=v[::2], seed=5, subsurface=sub)
        path = tmp_path / f"knit_{sub}.btfrs"
        disk = btfrs.materials.make("knit", size=24, views=v, lights=v[::2], seed=5, subsurface=sub, out=path)
        assert isinstance(disk.data, np.memmap) or not disk.data.flags.owndata
        np.testing.assert_array_equal(disk.data, mem.data)
        np.testing.assert_array_equal(disk.views, mem.views)
        np.testing.assert_array_equal(btfrs.Btf.load(path).data, mem.data)  # a plain .btfrs file


def test_a_failed_material_write_leaves_nothing(tmp_path):
    path = tmp_path / "bad.btfrs"
    with pytest.raises(InvalidArgumentError, match="unknown material"):
        btfrs.materials.make("velvet", size=16, out=path)
    with pytest.raises(ArgumentTypeError, match="out: expected a file path"):
        btfrs.materials.make("knit", size=16, out=3)
    with pytest.raises(InvalidArgumentError, match="views"):
        btfrs.materials.make("knit", size=16, views=np.array([[0.0, 0.0, -1.0]]), out=path)
    assert list(tmp_path.iterdir()) == []


def test_a_file_changed_on_disk_during_a_fit_is_an_error(tmp_path):
    path = tmp_path / "small.btfrs"
    btf = btfrs.materials.make("knit", size=16, out=path)
    btfrs.fit.ptm(btf)  # unchanged: fine
    st = path.stat()
    # Another process rewriting the file moves its modification time (and maybe its size).
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    with pytest.raises(FormatError, match="the file changed on disk during the ptm fit"):
        btfrs.fit.ptm(btf)
    with pytest.raises(FormatError, match="changed on disk during the analysis"):
        btfrs.synth.analyse(btf, textons=16, levels=1)
    fresh = btfrs.Btf.load(path, mmap=True)  # reopening it: the fit works again
    assert btfrs.fit.ptm(fresh).height == 16
    # A Btf in memory has no file to watch.
    btfrs.fit.ptm(btfrs.Btf.load(path))


@pytest.fixture(scope="module")
def medium(tmp_path_factory):
    """A ~52 MB BTF on disk (36 x 36 texels, 81 views x 41 lights): twice the 24 MB limit the
    per-texel fits are held to (the least they need here is 16 to 20 MB), at a quarter of the big
    sample's fitting time."""
    path = tmp_path_factory.mktemp("ooc") / "medium.btfrs"
    v = btfrs.directions.ubo81()
    btfrs.materials.make("bumps", size=36, views=v, lights=v[::2], seed=3, out=path)
    return path


@pytest.mark.parametrize("kind", [k for k, info in KINDS.items() if info["blockwise"] == "texels"])
def test_a_deterministic_fit_under_a_limit_equals_the_unlimited_one(medium, kind):
    # The fits whose every texel depends on its own values only (the registry's blockwise
    # "texels") do not change their algorithm under a limit: the same arrays, bit for bit, from
    # the memory-mapped file under a limit below half its size as from the same values in memory.
    mapped = btfrs.Btf.load(medium, mmap=True)
    assert mapped.data.nbytes > 2 * memory_size("limit", "24MB")
    opts = OPTIONS[kind]
    limited = btfrs.fit.fit(kind, mapped, memory_limit="24MB", **opts).arrays
    in_memory = btfrs.fit.fit(kind, btfrs.Btf.load(medium), **opts).arrays
    assert limited.keys() == in_memory.keys()
    for name in limited:
        np.testing.assert_array_equal(limited[name], in_memory[name], err_msg=name)
