"""Graph-cut Wang tile sets (paper 002 section 3.2): structure, seams, storage, tiling, errors."""

import numpy as np
import pytest

import btfrs
from btfrs import _native
from btfrs.exceptions import FormatError, InvalidArgumentError


def bricks(n: int, seed: int = 0, crop=(17, 11)) -> np.ndarray:
    """A photograph-like brick texture (mortar lines, per-brick tint, noise), cropped off its
    period so that plain tiling of it does not match at its borders."""
    r = np.random.default_rng(seed)
    size = n + 40
    y, x = np.mgrid[0:size, 0:size]
    bh, bw, m = 12, 26, 2
    row = y // bh
    off = (row % 2) * (bw // 2)
    mortar = ((y % bh) < m) | (((x + off) % bw) < m)
    tint = r.uniform(0.8, 1.2, size=(size // bh + 2, size // bw + 3))[row, (x + off) // bw]
    img = np.where(mortar[..., None], np.array([0.75, 0.72, 0.7]), np.array([0.55, 0.2, 0.12]) * tint[..., None])
    img = img + r.normal(0, 0.03, img.shape)
    return np.ascontiguousarray(img[crop[0]:crop[0] + n, crop[1]:crop[1] + n], dtype=np.float32)


@pytest.fixture(scope="module")
def brick_tiles():
    return btfrs.tiles.wang(bricks(128), tile=64, edge_height=16, colors=2, seed=5, progress=False)


@pytest.fixture(scope="module")
def sh_tiles():
    btf = btfrs.materials.make("bumps", size=64, seed=3)
    sh = btfrs.fit.sh(btf, light_coeffs=9, view_coeffs=9)
    return sh, btfrs.tiles.wang(sh, tile=32, edge_height=8, colors=2, seed=1, progress=False)


def test_tiles_sharing_an_edge_colour_share_its_strip(brick_tiles):
    # Independent of the synthesis details: every tile whose south colour is c has the same
    # outer h/4 rows along its bottom edge (outside the corner quadrants; the inner h/4 of the
    # band is the interior fill's overlap), and the same for the other three sides; tiles with
    # different colours there differ.
    ts = brick_tiles
    w, half = ts.tile, ts.edge_height // 2
    k = max(1, half // 2)
    bands = {
        0: lambda t: t[:k, half:w - half], 2: lambda t: t[w - k:, half:w - half],
        1: lambda t: t[half:w - half, w - k:], 3: lambda t: t[half:w - half, :k],
    }
    for side, band in bands.items():
        by_colour = {}
        for tid in range(ts.n_tiles):
            by_colour.setdefault(int(ts.codes[tid, side]), []).append(band(ts.texels[tid]))
        for c, group in by_colour.items():
            assert all(np.array_equal(group[0], g) for g in group), (side, c)
        assert not np.array_equal(by_colour[0][0], by_colour[1][0])
    # Canonical ids: ((n C + e) C + s) C + w.
    c = ts.colors
    for tid in range(ts.n_tiles):
        n, e, s, w_ = ts.codes[tid]
        assert tid == ((n * c + e) * c + s) * c + w_


def test_across_a_matching_edge_the_strip_continues(brick_tiles):
    # Tile A above tile B with A.south == B.north: A's bottom half band and B's top half band
    # are the two halves of one synthesized strip: texels on either side of the boundary are
    # vertically adjacent in the sample wherever the strip copied one patch (most columns).
    ts = brick_tiles
    w, half = ts.tile, ts.edge_height // 2
    sw = ts.source["dims"][1]
    a = next(t for t in range(ts.n_tiles) if ts.codes[t, 2] == 1)
    b = next(t for t in range(ts.n_tiles) if ts.codes[t, 0] == 1)
    above, below = ts.texels[a][w - 1, half:w - half].astype(int), ts.texels[b][0, half:w - half].astype(int)
    adjacent = np.mean(below - above == sw)
    # Unrelated tiles' rows (colour 0 below colour 1) are essentially never adjacent.
    c = next(t for t in range(ts.n_tiles) if ts.codes[t, 0] == 0)
    other = ts.texels[c][0, half:w - half].astype(int)
    assert adjacent > 0.6 and np.mean(other - above == sw) < 0.1, adjacent


def test_no_visible_seams_on_a_sample_that_does_not_tile(brick_tiles):
    # Issue 12 item 7: in a 16 x 16 tiling the neighbourhood error across tile edges must not
    # exceed the error inside tiles by more than 10%, while plain tiling of random crops of the
    # same sample (interior error 0: copies) shows its seams.
    ts = brick_tiles
    lay = ts.tiling(16, 16, seed=1)
    e = ts.seam_errors(lay, windows=400)
    assert e["edge"] <= 1.1 * e["interior"], e
    assert e["crops_edge"] > 3 * e["edge"], e
    assert e["crops_interior"] < 1e-9


def test_sh_domain_tiles_and_the_btfel_table(sh_tiles, tmp_path):
    sh, ts = sh_tiles
    assert ts.n_tiles == 16 and ts.model.kind == "sh"
    # The BTFel table: unique referenced texels, and the compact model reproduces the source
    # model's values at them (checked against the source model itself).
    assert np.all(np.diff(ts.btfels.astype(np.int64)) > 0)
    assert np.array_equal(np.unique(ts.texels), ts.btfels)
    assert np.array_equal(ts.btfels[ts.indices], ts.texels)
    v, l = [0.2, 0.1, 0.97], [-0.3, 0.4, 0.87]
    full = sh._m.evaluate(list(np.array(v) / np.linalg.norm(v)), list(np.array(l) / np.linalg.norm(l))).reshape(-1, 3)
    comp = ts.model._m.evaluate(list(np.array(v) / np.linalg.norm(v)), list(np.array(l) / np.linalg.norm(l))).reshape(-1, 3)
    np.testing.assert_array_equal(comp, full[ts.btfels])
    r = ts.report
    assert r["btfels"] == len(ts.btfels) and 0 < r["referenced"] <= 1
    assert r["total_bytes"] == r["table_bytes"] + r["index_bytes"] and r["table_bytes"] == ts.model.nbytes
    assert [s["step"] for s in r.steps] == ["corner sampling", "edge synthesis", "frame construction",
                                             "interior synthesis"]
    assert "referenced BTFels" in str(r)
    # Seamless in the SH domain too.
    e = ts.seam_errors(ts.tiling(12, 12, seed=3), windows=300)
    assert e["edge"] <= 1.1 * e["interior"] and e["crops_edge"] > 2 * e["edge"], e
    # Save / load round trip, and a corrupted index is refused.
    p = tmp_path / "bumps.tiles"
    ts.save(p)
    back = btfrs.load(p)
    assert isinstance(back, btfrs.tiles.TileSet)
    for name in ("codes", "texels", "btfels", "indices", "atlas"):
        np.testing.assert_array_equal(getattr(back, name), getattr(ts, name))
    np.testing.assert_array_equal(back.model._m.evaluate([0, 0, 1], [0, 0, 1]), ts.model._m.evaluate([0, 0, 1], [0, 0, 1]))
    assert back.report["btfels"] == ts.report["btfels"]
    bad = tmp_path / "bad.tiles"
    meta = {"tile": ts.tile, "edge_height": ts.edge_height, "colors": ts.colors, "report": ts.report.data,
            "source": ts.source}
    idx = ts.indices.astype(np.int32).copy()
    idx[0, 0, 0] = (idx[0, 0, 0] + 1) % len(ts.btfels)
    import json
    _native.save_container(str(bad), "tiles", json.dumps(meta),
                           [("codes", ts.codes), ("texels", ts.texels.astype(np.int32)),
                            ("btfels", ts.btfels.astype(np.int32)), ("indices", idx),
                            ("atlas", ts.atlas.astype(np.int32))])
    with pytest.raises(FormatError, match="do not reproduce"):
        btfrs.load(bad)


def test_same_seed_same_set_other_seed_other_set():
    tex = bricks(64, seed=2)
    a = btfrs.tiles.wang(tex, tile=32, edge_height=8, seed=3, progress=False)
    b = btfrs.tiles.wang(tex, tile=32, edge_height=8, seed=3, progress=False)
    c = btfrs.tiles.wang(tex, tile=32, edge_height=8, seed=4, progress=False)
    assert np.array_equal(a.texels, b.texels) and not np.array_equal(a.texels, c.texels)


def test_tilings_are_valid_stochastic_and_checked(brick_tiles):
    ts = brick_tiles
    lay = ts.tiling(32, 32, seed=1)
    ts.check(lay)
    assert lay.shape == (32, 32) and len(np.unique(lay)) == 16
    assert not np.array_equal(lay, ts.tiling(32, 32, seed=2))
    wrapped = ts.tiling(8, 8, seed=1, wrap=True)
    ts.check(wrapped, wrap=True)
    bad = lay.copy()
    bad[3, 4] ^= 1  # flips the west colour
    with pytest.raises(InvalidArgumentError, match=r"layout: cell \(row 3, column 3\)"):
        ts.check(bad)
    # A subset that cannot tile: one tile whose east and west colours differ.
    tid = ((0 * 2 + 1) * 2 + 0) * 2 + 0
    with pytest.raises(InvalidArgumentError, match="no valid 1 x 2 tiling"):
        ts.tiling(1, 2, tiles=[tid])
    # The atlas is itself a valid tiling (canonical arrangement): neighbours match.
    pos = ts.atlas_positions()
    a = ts.colors ** 2
    grid = np.zeros((a, a), dtype=np.uint32)
    for t, (r, c) in enumerate(pos):
        grid[r, c] = t
    ts.check(grid, wrap=True)


@pytest.mark.parametrize("kwargs, match", [
    (dict(tile=64, edge_height=40), "edge_height: 40 is larger than half the tile"),
    (dict(tile=256, edge_height=16), "tile: a 256 texel tile is larger than the 128 x 128 sample"),
    (dict(colors=1), "colors"),
    (dict(edge_height=7), "edge_height: expected an even number"),
    (dict(pixel_threshold=float("nan")), "pixel_threshold"),
    (dict(bogus=1), "bogus"),
])
def test_bad_options_name_the_argument(kwargs, match):
    with pytest.raises(InvalidArgumentError, match=match):
        btfrs.tiles.wang(bricks(128), progress=False, **kwargs)


def test_bad_samples_are_refused():
    tex = bricks(64)
    tex[3, 4, 1] = np.nan
    with pytest.raises(InvalidArgumentError, match=r"sample: value NaN at texel \(row 3, column 4\)"):
        btfrs.tiles.wang(tex, tile=32, edge_height=8, progress=False)
    with pytest.raises(btfrs.exceptions.ArgumentTypeError, match="source"):
        btfrs.tiles.wang("bricks.png", progress=False)
    with pytest.raises(InvalidArgumentError, match="rows"):
        btfrs.tiles.wang(bricks(64), tile=32, edge_height=8, progress=False).tiling(0, 3)


def test_every_model_selects_texels_exactly():
    # The model contract's per-texel arrays: the model of a subset of texels evaluates exactly
    # as the full model at those texels, for every registered model.
    btf = btfrs.materials.make("bumps", size=8, seed=2)
    idx = [5, 0, 63, 17, 17, 40]
    v = [0.3, -0.2, 0.93]
    l = [-0.4, 0.1, 0.91]
    v = list(np.array(v) / np.linalg.norm(v))
    l = list(np.array(l) / np.linalg.norm(l))
    for kind in btfrs.model_kinds():
        m = btfrs.fit.fit(kind, btf)
        sub = m._m.select_texels(idx)
        assert sub.kind == kind and sub.dims == (1, len(idx))
        full = m._m.evaluate(v, l).reshape(-1, 3)
        np.testing.assert_array_equal(sub.evaluate(v, l).reshape(-1, 3), full[idx], err_msg=kind)
    with pytest.raises(InvalidArgumentError, match="texels: texel 64 is outside the 8 x 8 model"):
        m._m.select_texels([64])
