"""Wang tile sets through the renderers: GPU vs CPU, BTFel model vs source model, errors."""

import numpy as np
import pytest

import btfrs
from btfrs.exceptions import ArgumentTypeError, InvalidArgumentError


def psnr(a, b):
    peak = max(float(a.max()), float(b.max()))
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(peak * peak / mse)


@pytest.fixture(scope="module")
def setup():
    btf = btfrs.materials.make("bumps", size=64, seed=3)
    sh = btfrs.fit.sh(btf, light_coeffs=9, view_coeffs=9)
    ts = btfrs.tiles.wang(sh, tile=32, edge_height=8, colors=2, seed=1, progress=False)
    cam = btfrs.Camera.look_at([0.0, -3.2, 1.6], [0.0, 0.0, 0.0], 40)
    lights = [btfrs.PointLight([2.0, -2.5, 3.0], 9.0)]
    return btf, sh, ts, cam, lights


@pytest.mark.parametrize("scene", ["cylinder", "sphere", "plane"])
def test_gpu_matches_cpu_through_tile_maps(setup, scene):
    btf, sh, ts, cam, lights = setup
    sc = getattr(btfrs.Scene, scene)()
    lay = ts.tiling(6, 6, seed=2, wrap=(True, False))
    g = btfrs.render(ts.model, sc, cam, lights, size=(160, 160), tiles=ts, layout=lay)
    c = btfrs.render(ts.model, sc, cam, lights, size=(160, 160), tiles=ts, layout=lay, backend="cpu")
    assert (c.sum(-1) > 0).mean() > 0.1
    assert psnr(g, c) >= 40.0


def test_btfel_model_and_source_model_draw_the_same_tiling(setup):
    # The compact BTFel model looked up through the atlas of table indices, and the source
    # model through the atlas of sample texels, shade the same texels: identical CPU images.
    btf, sh, ts, cam, lights = setup
    lay = ts.tiling(4, 5, seed=3)
    sc = btfrs.Scene.cylinder()
    a = btfrs.render(ts.model, sc, cam, lights, size=(96, 96), tiles=ts, layout=lay, backend="cpu")
    b = btfrs.render(sh, sc, cam, lights, size=(96, 96), tiles=ts, layout=lay, backend="cpu")
    np.testing.assert_array_equal(a, b)
    # And the raw BTF the model was fitted to, through the same tiles: GPU vs CPU, and close to
    # the model's picture (the fit's own error).
    r_cpu = btfrs.render(btf, sc, cam, lights, size=(96, 96), tiles=ts, layout=lay, backend="cpu")
    r_gpu = btfrs.render(btf, sc, cam, lights, size=(96, 96), tiles=ts, layout=lay)
    assert psnr(r_gpu, r_cpu) >= 40.0
    assert psnr(a, r_cpu) > 20.0


def test_a_different_layout_is_a_different_image_and_swapping_sets_needs_no_retiling(setup):
    btf, sh, ts, cam, lights = setup
    sc = btfrs.Scene.plane(2.0)
    l1, l2 = ts.tiling(4, 4, seed=1), ts.tiling(4, 4, seed=2)
    a = btfrs.render(ts.model, sc, cam, lights, size=(96, 96), tiles=ts, layout=l1, backend="cpu")
    b = btfrs.render(ts.model, sc, cam, lights, size=(96, 96), tiles=ts, layout=l2, backend="cpu")
    assert psnr(a, b) < 35.0
    other = btfrs.fit.sh(btfrs.materials.make("weave", size=64, seed=1), light_coeffs=9, view_coeffs=9)
    ts2 = btfrs.tiles.wang(other, tile=32, edge_height=8, colors=2, seed=1, progress=False)
    c = btfrs.render(ts2.model, sc, cam, lights, size=(96, 96), tiles=ts2, layout=l1, backend="cpu")
    assert c.shape == a.shape and psnr(a, c) < 30.0


def test_tile_render_errors_name_the_argument(setup):
    btf, sh, ts, cam, lights = setup
    sc = btfrs.Scene.plane(2.0)
    lay = ts.tiling(2, 2)
    with pytest.raises(InvalidArgumentError, match="tiles: give both"):
        btfrs.render(ts.model, sc, cam, lights, size=32, tiles=ts)
    small = btfrs.fit.ptm(btfrs.materials.make("bumps", size=16, seed=3))
    with pytest.raises(InvalidArgumentError, match="model: the tile set was synthesized from a 64 x 64"):
        btfrs.render(small, sc, cam, lights, size=32, tiles=ts, layout=lay)
    with pytest.raises(InvalidArgumentError, match="layout: tile 16 does not exist"):
        btfrs.render(ts.model, sc, cam, lights, size=32, tiles=ts, layout=np.full((2, 2), 16))
    tm = ts.tile_map(ts.model, lay)
    with pytest.raises(InvalidArgumentError, match="not both"):
        btfrs.render(ts.model, sc, cam, lights, size=32, tile_map=tm, coords=np.zeros((2, 2, 2), np.uint16))
    bad = btfrs.rendering.TileMap(tm.atlas, tm.tile, np.full((2, 2, 2), 9, np.uint32))
    with pytest.raises(InvalidArgumentError, match="tiles: layout cell \\(row 0, column 0\\) names atlas tile"):
        btfrs.render(ts.model, sc, cam, lights, size=32, tile_map=bad, backend="cpu")
    with pytest.raises(ArgumentTypeError, match="tile_map"):
        btfrs.render(ts.model, sc, cam, lights, size=32, tile_map=btfrs.rendering.TileMap(tm.atlas * 1.0, 32, tm.layout))
