"""btfrs.dask: zarr storage in btfrs's layout and the fits run over texel tiles on a Dask
LocalCluster (2 worker processes), each against the local fit of the same BTF."""

import logging
import os

import numpy as np
import pytest

import btfrs
from btfrs import _native
from btfrs.tools.bench import light_basis_steps
from btfrs.exceptions import ArgumentTypeError, ClusterError, FormatError, InvalidArgumentError

dask = pytest.importorskip("dask")
distributed = pytest.importorskip("distributed")
zarr = pytest.importorskip("zarr")
import btfrs.dask as bd  # noqa: E402

# distributed's own start-up and shutdown warnings (ports, event loops, closing sockets) are not
# this module's business; every test still fails on btfrs's warnings of other categories.
pytestmark = [
    pytest.mark.filterwarnings("ignore::DeprecationWarning"),
    pytest.mark.filterwarnings("ignore::ResourceWarning"),
    pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning"),
    pytest.mark.filterwarnings("ignore:.*[Pp]ort.*:UserWarning"),
    # An in-memory BTF travels in the task graph (what dask warns of above a few MiB).
    pytest.mark.filterwarnings("ignore:Sending large graph:UserWarning"),
]

# Every model the blockwise contract fits bit for bit, with options that make the 8-bit and
# masked paths run (RBF and bilinear, equal to rounding, are LIGHT_PCA below).
FITS = [
    ("ptm", {}),
    ("ptm", {"kind": "lrgb", "bits": 32}),
    ("hsh", {"order": 3}),
    ("sh", {"view_coeffs": 16, "light_coeffs": 16}),
    ("lafortune", {"lobes": 1}),
    ("lafortune_view", {"lobes": 1}),
    ("srf", {}),
    # 48 x 48 = 2304 texels: more than the range finder's 2048-texel sample, so the seeded
    # sample is gathered from the tiles.
    ("lpca", {"clusters": 8, "components": 3}),
]

# The light bases (per-slot moments reduced on the cluster), both colour groupings.
LIGHT_PCA = [
    ("rbf", {"components": 6}),
    ("bilinear", {"components": 5, "colour": "ycc", "chroma_components": 2}),
]


@pytest.fixture(scope="module")
def sample():
    u = _native.ubo81()
    return btfrs.materials.make("bumps", size=48, views=u[::6], lights=u[::3], seed=3)


@pytest.fixture(scope="module")
def masked(sample):
    mask = np.ones((sample.n_views, sample.n_lights), dtype=bool)
    mask[:, ::4] = False
    mask[3, :] = False
    mask[3, 1] = True
    return btfrs.Btf(sample.data, sample.views, sample.lights, mask)


def _same_model(a, b):
    x, y = a.arrays, b.arrays
    assert sorted(x) == sorted(y)
    for k in y:
        assert x[k].dtype == y[k].dtype and x[k].shape == y[k].shape, k
        assert np.array_equal(x[k], y[k]), f"array {k} differs"


def _same_light_basis(m, local, btf):
    """A staged RBF / bilinear fit against the local one: the same layout, and every
    evaluation equal to rounding (each principal function may have the other sign, its
    coefficients with it, so the arrays themselves need not be equal)."""
    assert type(m) is type(local)
    x, y = m.arrays, local.arrays
    assert sorted(x) == sorted(y)
    for k in y:
        assert x[k].dtype == y[k].dtype and x[k].shape == y[k].shape, k
    assert np.array_equal(x["layout"], y["layout"]) and np.array_equal(x["views"], y["views"])
    assert m.report == local.report
    # The first principal function's magnitude is fixed by the data, whatever its sign.
    assert np.allclose(np.abs(x["table"]), np.abs(y["table"]), atol=1e-4)
    # Up to sign, the same functions and every decoded coefficient within one 8-bit step (a
    # rounding difference can cross a quantisation boundary; a different fit is many steps off).
    assert light_basis_steps(m, local) <= 1.01
    peak = 0.0
    worst = 0.0
    for v, l in [(0, 0), (3, 11), (btf.n_views - 1, btf.n_lights - 1), (5, 20)]:
        a = m.evaluate(btf.views[v], btf.lights[l])
        b = local.evaluate(btf.views[v], btf.lights[l])
        peak = max(peak, float(np.abs(b).max()))
        worst = max(worst, float(np.abs(a - b).max()))
    # Float rounding only (measured below 1e-6); one 8-bit step of a coefficient is ~1e-3.
    assert worst <= 2e-3 * peak, (worst, peak)
    assert m.error(btf).rmse == pytest.approx(local.error(btf).rmse, rel=1e-3)


def _close_reports(a, b):
    assert sorted(a) == sorted(b)
    for k, v in b.items():
        if isinstance(v, float):
            assert a[k] == pytest.approx(v, rel=1e-9), k
        else:
            assert a[k] == v, k


def test_without_a_cluster_the_threaded_scheduler_fits_the_same_model(sample):
    # Before the module's cluster exists: no client, so dask's threads run the tasks (the native
    # fits release the GIL).
    assert bd._client() is None
    arr = bd.from_btf(sample, chunks=20)
    assert arr.tiles == ((20, 20, 8), (20, 20, 8))
    local = btfrs.fit.ptm(sample)
    m = bd.fit("ptm", arr)
    assert isinstance(m, btfrs.models.Ptm)
    _same_model(m, local)
    assert m.fit_seconds > 0
    # The light bases' moments are merged in a tree of delayed tasks here (no futures).
    _same_light_basis(bd.fit("rbf", arr, components=4), btfrs.fit.rbf(sample, components=4), sample)


def test_hot_values_on_tile_edges_are_repaired_as_in_memory(sample):
    # The robust screen's spatial neighbours cross tile edges: a tile is screened with a
    # one-texel halo, so the blockwise fit repairs exactly the values the local fit repairs.
    # Hot values on both sides of the tile edges at rows/columns 19|20 and 39|40, a pair of
    # them side by side at one (view, light), and a misfired flash (a bad image, excluded).
    d = sample.data.copy()
    for r, c, v, l in [(19, 19, 3, 5), (20, 19, 3, 5), (20, 20, 7, 11), (39, 40, 1, 2), (0, 0, 0, 0), (47, 47, 13, 26)]:
        d[r, c, v, l, 1] *= 1000.0
    d[:, :, 4, 9] *= 0.15
    # A bright patch (every light of view 6, blue) on the five texels across the corner of the
    # tile edges beside texel (19, 19): that texel's bright value at one pair is in keeping
    # with its spatial neighbours, so not flagged, and only a tile that sees across its edges
    # knows.
    for r, c in [(18, 20), (19, 20), (20, 18), (20, 19), (20, 20)]:
        d[r, c, 6, :, 2] *= 1000.0
    d[19, 19, 6, 8, 2] *= 1000.0
    hot = btfrs.Btf(d, sample.views, sample.lights)
    arr = bd.from_btf(hot, chunks=20)
    for kw in ({}, {"exclude_bad_images": True}, {"robust": False}):
        local, m = btfrs.fit.ptm(hot, **kw), bd.fit("ptm", arr, **kw)
        _same_model(m, local)
        assert m.report == local.report, kw
    rep = btfrs.fit.ptm(hot).report["robust"]
    assert rep["values_flagged"] == 6 and {(p["view"], p["light"]) for p in rep["bad_images"]} == {(4, 9)}
    # The repairs matter: without them the tile fits differ from the robust ones.
    plain, robust = bd.fit("ptm", arr, robust=False), bd.fit("ptm", arr)
    assert not np.array_equal(plain.arrays["coeffs_q"], robust.arrays["coeffs_q"])


@pytest.fixture(scope="module")
def client():
    # Failed tasks are not retried, so the dying-worker test fails at once (the default retries
    # would let the poisoned task kill the workers three more times).
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                           dashboard_address=None, silence_logs=logging.CRITICAL)
        c = distributed.Client(cluster)
        yield c
        c.close()
        cluster.close()


@pytest.fixture(scope="module")
def stored(tmp_path_factory, sample):
    p = tmp_path_factory.mktemp("zarr") / "bumps.zarr"
    assert bd.save_zarr(sample, p, chunks=16) == str(p)
    return p


def test_zarr_round_trip_is_exact_and_chunked_by_texel_tiles(stored, sample):
    arr = bd.open(stored)
    assert arr.shape == sample.shape
    assert arr.data.chunksize == (16, 16, sample.n_views, sample.n_lights, 3)
    assert np.array_equal(np.asarray(arr.data.compute()), sample.data)
    assert np.array_equal(arr.views, sample.views) and np.array_equal(arr.lights, sample.lights)
    assert arr.mask is None
    assert np.array_equal(arr.to_btf().data, sample.data)
    with pytest.raises(InvalidArgumentError, match="^path: .* exists; pass overwrite=True"):
        bd.save_zarr(sample, stored)


@pytest.mark.parametrize("kind,options", FITS, ids=[f"{k}-{i}" for i, (k, _) in enumerate(FITS)])
def test_every_blockwise_model_on_a_local_cluster_equals_the_local_fit(client, stored, sample, kind, options):
    local = btfrs.fit.fit(kind, sample, **options)
    m = bd.fit(kind, bd.open(stored), **options)
    assert type(m) is type(local)
    _same_model(m, local)
    _close_reports(m.report, local.report)
    # Saved like any other model.
    # The error sums run in parallel (their order varies from run to run): equal to rounding.
    assert m.error(sample).rmse == pytest.approx(local.error(sample).rmse, rel=1e-12)


@pytest.mark.parametrize("kind,options", [("ptm", {}), ("lpca", {"clusters": 6, "components": 2}),
                                          ("srf", {}), ("sh", {"view_coeffs": 9, "light_coeffs": 16})])
def test_a_masked_btf_fits_the_same_on_the_cluster(client, tmp_path, masked, kind, options):
    p = bd.save_zarr(masked, tmp_path / "masked.zarr", chunks=20)
    arr = bd.open(p)
    assert np.array_equal(arr.mask, masked.mask)
    _same_model(bd.fit(kind, arr, **options), btfrs.fit.fit(kind, masked, **options))


@pytest.mark.parametrize("kind,options", LIGHT_PCA, ids=[k for k, _ in LIGHT_PCA])
def test_light_bases_on_a_local_cluster_evaluate_as_the_local_fit(client, stored, sample, masked, tmp_path, kind,
                                                                   options):
    calls = []
    m = bd.fit(kind, bd.open(stored), progress=lambda d, t: calls.append((d, t)), **options)
    _same_light_basis(m, btfrs.fit.fit(kind, sample, **options), sample)
    # Three stages on the cluster, the robust screen, the moments and the projection, each
    # counting the 9 tiles.
    ends = [c for c in calls if c[0] == c[1]]
    assert ends == [(9, 9)] * 3 and all(0 < d <= t for d, t in calls), calls
    # With a mask (one view slot left with a single light: pooled from its neighbours).
    arr = bd.open(bd.save_zarr(masked, tmp_path / "masked.zarr", chunks=20))
    local = btfrs.fit.fit(kind, masked, **options)
    assert local.report["pooled_slots"], "the masked sample should pool a slot"
    _same_light_basis(bd.fit(kind, arr, **options), local, masked)


def test_a_memory_mapped_btf_is_read_by_path_on_the_workers(client, tmp_path, sample):
    f = tmp_path / "s.btfrs"
    sample.save(f)
    mm = btfrs.Btf.load(f, mmap=True)
    arr = bd.from_btf(mm, chunks=24)
    # The graph reads tiles by path: no task carries the values.
    assert all(not isinstance(v, np.ndarray) or v.nbytes < 1e5 for v in dict(arr.data.dask).values())
    _same_model(bd.fit("hsh", arr, order=2), btfrs.fit.hsh(sample, order=2))
    # A file rewritten afterwards is detected on the workers, not read as the same BTF.
    os.utime(f, ns=(1, 1))
    with pytest.raises(FormatError, match="changed on disk"):
        bd.fit("hsh", arr, order=2)


def test_bad_input_gets_clear_errors(client, tmp_path, stored, sample):
    arr = bd.open(stored)
    # The blockwise limit is each view slot's exact eigenproblem, min(3 n^2, 3 x lights) rows: 867 x
    # 867 for resolution 17 under 300 lights (under this sample's 27 lights it is 81 x 81).
    i = np.arange(300)
    th, ph = 1.2 * (i + 0.5) / 300, 2.4 * i
    lights = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)
    wide = btfrs.Btf(np.full((4, 4, 1, 300, 3), 0.5, np.float32), [[0.0, 0.0, 1.0]], lights)
    with pytest.raises(InvalidArgumentError, match="^resolution: the blockwise rbf fit solves an exact 867 x 867"):
        bd.fit("rbf", bd.from_btf(wide, chunks=4), resolution=17)
    with pytest.raises(InvalidArgumentError, match="^width: expected a number > 0"):
        bd.fit("rbf", arr, width=-1.0)
    with pytest.raises(InvalidArgumentError, match="^model: "):
        bd.fit("nope", arr)
    with pytest.raises(InvalidArgumentError, match="^memory_limit: a Dask fit is bounded by its workers"):
        bd.fit("ptm", arr, memory_limit="1GB")
    # Options are checked by the model itself on the worker; the error comes back as itself.
    with pytest.raises(InvalidArgumentError, match="^lobes: "):
        bd.fit("lafortune", arr, lobes=2.5)
    with pytest.raises(InvalidArgumentError, match="^reduced_dims: expected at least 1 for a blockwise fit"):
        bd.fit("lpca", arr, reduced_dims=0)
    with pytest.raises(ArgumentTypeError, match="^arr: expected a btfrs.dask.BtfArray"):
        bd.fit("ptm", arr.data)
    # A NaN in one tile: the tile's fit names the data.
    bad = sample.data.copy()
    bad[30, 40, 2, 5, 1] = np.nan
    nan_arr = bd.BtfArray(dask.array.from_array(bad, chunks=(16, 16, -1, -1, -1)), sample.views, sample.lights)
    with pytest.raises(InvalidArgumentError, match="^data: "):
        bd.fit("ptm", nan_arr)
    with pytest.raises(InvalidArgumentError, match="^btf: rows 16 to 31 hold values that are not finite"):
        bd.save_zarr(nan_arr, tmp_path / "nan.zarr", chunks=16)
    assert not os.listdir(tmp_path)
    # A chunking that splits a texel's values.
    with pytest.raises(InvalidArgumentError, match="^data: expected chunks that hold all lights"):
        bd.BtfArray(dask.array.from_array(sample.data, chunks=(16, 16, -1, 9, -1)), sample.views, sample.lights)


def _write_group(path, data, views, lights, attrs=None, chunks=None):
    g = zarr.open_group(str(path), mode="w")
    g.attrs.update(attrs if attrs is not None else {"btfrs": "btf", "layout_version": bd.LAYOUT_VERSION})
    g.create_array("data", shape=data.shape, dtype=data.dtype, chunks=chunks or data.shape)[...] = data
    g.create_array("views", shape=views.shape, dtype=views.dtype)[...] = views
    g.create_array("lights", shape=lights.shape, dtype=lights.dtype)[...] = lights
    return path


def test_zarr_groups_in_another_layout_are_format_errors(tmp_path, sample):
    d = sample.data[:8, :8]
    v, l = sample.views, sample.lights
    with pytest.raises(FormatError, match="data has dtype float64, expected float32"):
        bd.open(_write_group(tmp_path / "f64.zarr", d.astype(np.float64), v, l))
    with pytest.raises(FormatError, match="a chunk must hold all views, lights and RGB"):
        bd.open(_write_group(tmp_path / "split.zarr", d, v, l, chunks=(4, 4, 7, 27, 3)))
    with pytest.raises(FormatError, match="data has shape .* expected \\(H, W, V, L, 3\\)"):
        bd.open(_write_group(tmp_path / "img.zarr", d.reshape(8, 8, -1), v, l))
    with pytest.raises(FormatError, match="not a btfrs BTF"):
        bd.open(_write_group(tmp_path / "other.zarr", d, v, l, attrs={}))
    with pytest.raises(FormatError, match="views is float32"):
        bd.open(_write_group(tmp_path / "v32.zarr", d, v.astype(np.float32), l))
    with pytest.raises(FileNotFoundError):
        bd.open(tmp_path / "missing.zarr")


def test_an_interrupted_save_leaves_nothing(client, tmp_path, sample):
    def fail_late(x, block_info=None):
        if block_info[0]["chunk-location"][0] >= 1:
            raise RuntimeError("disk went away")
        return x

    arr = bd.from_btf(sample, chunks=16)
    broken = bd.BtfArray(arr.data.map_blocks(fail_late, dtype=np.float32), sample.views, sample.lights)
    with pytest.raises(RuntimeError, match="disk went away"):
        bd.save_zarr(broken, tmp_path / "out.zarr", chunks=16)
    assert os.listdir(tmp_path) == []


def test_a_worker_that_dies_mid_fit_is_a_cluster_error_and_a_rerun_works(client, stored, sample):
    def die_on_one_tile(x, block_info=None):
        if block_info[0]["chunk-location"][:2] == (1, 2):
            os._exit(1)  # the worker process dies, as one killed by the kernel would
        return x

    arr = bd.open(stored)
    poisoned = bd.BtfArray(arr.data.map_blocks(die_on_one_tile, dtype=np.float32), arr.views, arr.lights)
    with pytest.raises(ClusterError, match="^cluster: the Dask cluster failed during the ptm fit"):
        bd.fit("ptm", poisoned)
    client.wait_for_workers(2, timeout=60)
    _same_model(bd.fit("ptm", arr), btfrs.fit.ptm(sample))


def test_progress_reports_every_stage_to_its_end(client, stored, sample):
    calls = []
    m = bd.fit("lpca", bd.open(stored), clusters=4, components=2, progress=lambda d, t: calls.append((d, t)))
    _same_model(m, btfrs.fit.lpca(sample, clusters=4, components=2))
    # One count per task in each of the four stages run on the cluster (the robust screen's,
    # the sample's and the projection's 9 tiles, the 4 clusters), each ending at its total.
    ends = [c for c in calls if c[0] == c[1]]
    assert [t for _, t in ends][-1] == 4 and 9 in [t for _, t in ends] and len(ends) == 4, calls
    assert all(0 < d <= t for d, t in calls)


def test_light_basis_steps_counts_quantisation_steps(sample):
    # The measure the staged light bases are held to must see a real difference: a copy is 0
    # steps, a copy with one code moved by 3 is 3, the fit of other data is inf.
    m = btfrs.fit.bilinear(sample, components=3)
    assert light_basis_steps(m, m) == 0.0
    arrays = dict(m.arrays)
    q = arrays["coeffs_q"].copy()
    q[0, 0, 0, 0] = q[0, 0, 0, 0] + 3 if q[0, 0, 0, 0] < 250 else q[0, 0, 0, 0] - 3
    arrays["coeffs_q"] = q
    moved = type(m).from_arrays(arrays)
    assert light_basis_steps(moved, m) == pytest.approx(3.0, rel=1e-4)
    u = _native.ubo81()
    other = btfrs.materials.make("knit", size=48, views=u[::6], lights=u[::3], seed=7)
    assert light_basis_steps(btfrs.fit.bilinear(other, components=3), m) == float("inf")
