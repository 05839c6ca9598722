"""Synthesis (paper 000 section 4): analysis, k-coherence, jump map, quality, expansion, rendering."""

import os

import numpy as np
import pytest

import btfrs
from btfrs import synth
from btfrs.tools.baselines import crop
from btfrs.exceptions import InvalidArgumentError


@pytest.fixture(scope="module")
def sample():
    """A non-periodic 48^2 window of the 64^2 bumps (the built-in materials tile; a crop does not,
    as a measured sample would not): a stochastic material, what patch synthesis is for."""
    return crop(btfrs.materials.make("bumps", size=64, seed=1), slice(5, 53), slice(9, 57))


@pytest.fixture(scope="module")
def an(sample):
    return synth.analyse(sample, textons=512, seed=0)


def test_analysis_tables_match_numpy(an):
    assert (an.height, an.width, an.levels) == (48, 48, 3)
    assert an.textons == [512, 512, 144]  # coarser levels: at most one texton per pixel
    m = an.dots(0)
    d = an.distances(0).astype(np.float64)
    diag = np.diag(m)
    # The paper's three-lookup form t_i.t_i - 2 t_i.t_j + t_j.t_j gives the stored table.
    np.testing.assert_allclose(d, diag[:, None] - 2 * m + diag[None, :], atol=1e-4 * diag.max())
    t = an.texton_map(0)
    assert t.shape == (48, 48) and t.dtype == np.uint16 and t.max() < 512


def test_similar_neighbourhoods_match_a_brute_force_search():
    rng = np.random.default_rng(3)
    tex = rng.random((14, 15, 2)).astype(np.float32)
    a = synth.analyse(tex, textons=14 * 15, levels=1, m=5, neighbourhoods=(1,))
    idx, dist = a.similar(neighbourhood=1)
    t64 = tex.astype(np.float64)
    for (y, x) in [(1, 1), (6, 9), (12, 13)]:
        win = t64[y - 1:y + 2, x - 1:x + 2]
        cands = []
        for qy in range(1, 13):
            for qx in range(1, 14):
                if abs(qy - y) <= 1 and abs(qx - x) <= 1:
                    continue
                cands.append((((t64[qy - 1:qy + 2, qx - 1:qx + 2] - win) ** 2).sum(), qy * 15 + qx))
        cands.sort()
        assert list(idx[y, x]) == [c[1] for c in cands[:5]]
        np.testing.assert_allclose(dist[y, x], [c[0] for c in cands[:5]], rtol=1e-5)
    assert (idx[0] == -1).all()


def test_kcoherence_is_deterministic_and_stays_in_the_sample(an):
    a = synth.kcoherence(an, size=(96, 80), k=3, neighbourhood=2, levels=3, seed=7)
    assert a.shape == (96, 80, 2) and a.dtype == np.uint16
    # Interior pixels only (windows of radius 2 inside the 48^2 sample).
    assert a.min() >= 2 and a[..., 0].max() <= 45 and a[..., 1].max() <= 45
    np.testing.assert_array_equal(a, synth.kcoherence(an, size=(96, 80), k=3, seed=7))
    assert (a != synth.kcoherence(an, size=(96, 80), k=3, seed=8)).any()


def test_quality_beats_random_placement_and_tiling(an):
    size = (192, 192)
    kc = synth.quality(an, synth.kcoherence(an, size=size, k=3, neighbourhood=2, levels=3, seed=7))
    tiled = synth.quality(an, synth.tiled((48, 48), size))
    rnd = synth.quality(an, synth.random_placement((48, 48), size, seed=1))
    # Random placement: far from every sample neighbourhood, seams everywhere.
    assert kc.nn_distance < 0.2 * rnd.nn_distance
    assert kc.seam < 0.5 * rnd.seam and kc.seam_mean < 0.1 * rnd.seam_mean
    # Plain tiling of a sample that does not tile: straight seam lines and full repetition.
    # (Its windows away from the seams are the sample itself, so its mean nn_distance is low.)
    assert kc.seam < 0.5 * tiled.seam
    assert kc.repetition < 0.5 * tiled.repetition
    assert tiled.repetition == pytest.approx(1 - 48 / 192)
    # Coherence is descriptive: patches, not single pixels, and not one whole sample.
    assert rnd.coherence < 0.01 < kc.coherence < tiled.coherence


def test_jump_map_is_coherent_but_worse_matched_than_kcoherence(an):
    jm = synth.jump_map(an, size=128, neighbourhood=2, jump=0.05, seed=3)
    assert jm.shape == (128, 128, 2)
    qj = synth.quality(an, jm)
    qk = synth.quality(an, synth.kcoherence(an, size=128, seed=3))
    rnd = synth.quality(an, synth.random_placement((48, 48), 128, seed=1))
    assert qj.coherence > 0.5 and qj.nn_distance < 0.5 * rnd.nn_distance
    assert qk.nn_distance < qj.nn_distance


def test_toroidal_output_tiles(an):
    # Rolling a map by half its size moves its wrap-around edges into the middle: a toroidal map
    # shows no seam line there, an ordinary one does.
    tor = synth.kcoherence(an, size=96, k=3, toroidal=True, seed=5)
    flat = synth.kcoherence(an, size=96, k=3, toroidal=False, seed=5)
    roll = lambda c: np.ascontiguousarray(np.roll(c, (48, 48), axis=(0, 1)))
    q_tor, q_flat = synth.quality(an, roll(tor)), synth.quality(an, roll(flat))
    assert q_tor.seam < 0.6 * q_flat.seam, (q_tor, q_flat)


def test_analysis_save_load_round_trip(an, tmp_path):
    p = tmp_path / "an.btfrs"
    an.save(p)
    b = btfrs.load(p)
    assert isinstance(b, synth.Analysis) and b.textons == an.textons and b.neighbourhoods == an.neighbourhoods
    np.testing.assert_array_equal(b.distances(1), an.distances(1))
    np.testing.assert_array_equal(synth.kcoherence(b, size=64, seed=2), synth.kcoherence(an, size=64, seed=2))
    assert not [f for f in os.listdir(tmp_path) if f != "an.btfrs"]  # no temporary left behind


def test_rgb_texture_synthesis():
    # Data independence: a plain RGB texture (uint8) goes through the same code.
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:40, 0:40]
    tex = np.stack([(np.sin(x / 2.0 + y / 5.0) > 0) * 200, (x * 6) % 256, (y * 6) % 256], -1).astype(np.uint8)
    tex = np.clip(tex.astype(int) + rng.integers(0, 10, tex.shape), 0, 255).astype(np.uint8)
    a = synth.analyse(tex, textons=256, levels=2)
    assert a.source == "texture" and a.dim == 3
    c = synth.kcoherence(a, size=100, k=2, levels=2, seed=1)
    out = synth.apply(tex, c)
    assert out.shape == (100, 100, 3) and out.dtype == np.uint8
    np.testing.assert_array_equal(out[10, 20], tex[c[10, 20, 1], c[10, 20, 0]])
    q, r = synth.quality(a, c), synth.quality(a, synth.random_placement(tex.shape, 100))
    assert q.nn_distance < 0.2 * r.nn_distance


def test_expanded_btf_is_a_lazy_view(sample):
    small = sample.select(views=[0, 5, 20], lights=slice(0, 81, 4))
    c = synth.random_placement((48, 48), (30, 20), seed=4)
    big = small.expand(c)
    assert big.shape == (30, 20, 3, small.n_lights, 3)
    assert big.nbytes == small.nbytes + c.nbytes
    full = big.to_btf()
    np.testing.assert_array_equal(full.data[7, 11], small.data[c[7, 11, 1], c[7, 11, 0]])
    np.testing.assert_array_equal(big.image(1, 2), full.image(1, 2))
    np.testing.assert_array_equal(big.abrdf(3, 4), full.abrdf(3, 4))
    with pytest.raises(InvalidArgumentError, match="coords"):
        small.expand(np.full((4, 4, 2), 48, np.uint16))


def test_render_through_the_coordinate_map_equals_rendering_the_expanded_btf(sample, an):
    # A PTM fitted per texel: fitting the expanded BTF gives each output texel the coefficients
    # of its sample texel, so rendering the sample's fit through the map must give the same image.
    small = sample.select(views=[0, 3, 10, 25], lights=None)
    cmap = synth.kcoherence(an, size=(40, 56), k=3, seed=1)
    # Floats (bits=32): 8-bit planes take each plane's range over the fitted texels, which differ.
    ptm_small = btfrs.fit.ptm(small, bits=32)
    ptm_big = btfrs.fit.ptm(small.expand(cmap).to_btf(), bits=32)
    scene = btfrs.Scene.plane()
    cam = btfrs.Camera.look_at(eye=[0, -3, 2], target=[0, 0, 0], fov_deg=40)
    lights = [btfrs.DirectionalLight(direction=[0.3, 0.2, 1.0], intensity=1.0)]
    a = btfrs.render(ptm_small, scene, cam, lights, size=96, coords=cmap, backend="cpu")
    b = btfrs.render(ptm_big, scene, cam, lights, size=96, backend="cpu")
    assert a.std() > 0.01
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)
    g = btfrs.render(ptm_small, scene, cam, lights, size=96, coords=cmap, backend="gpu")
    np.testing.assert_allclose(g, a, rtol=2e-3, atol=2e-4)


def test_bad_input_names_the_parameter(an, sample):
    with pytest.raises(InvalidArgumentError, match="^k: .*10"):
        synth.kcoherence(an, size=64, k=11)
    with pytest.raises(InvalidArgumentError, match="^size: "):
        synth.kcoherence(an, size=(16, 64), neighbourhood=2, levels=3)
    with pytest.raises(InvalidArgumentError, match="^levels: "):
        synth.kcoherence(an, size=64, levels=4)
    with pytest.raises(InvalidArgumentError, match="^levels: "):
        synth.kcoherence(an, size=256, neighbourhood=4, levels=3)  # 12^2 coarsest level too small
    with pytest.raises(InvalidArgumentError, match="^textons: "):
        synth.analyse(np.zeros((8, 8, 3), np.float32), textons=65, levels=1)
    with pytest.raises(InvalidArgumentError, match="^levels: "):
        synth.analyse(np.zeros((8, 8, 3), np.float32), textons=8, levels=3)
    with pytest.raises(InvalidArgumentError, match="^features: "):
        synth.analyse(sample, features="gabor")
    with pytest.raises(TypeError, match="^an: "):
        synth.kcoherence(np.zeros((4, 4, 3)), size=64)
    with pytest.raises(TypeError, match="^coords: "):
        synth.quality(an, np.zeros((8, 8, 2), np.int64))
    with pytest.raises(InvalidArgumentError, match="^coords: "):
        synth.quality(an, np.full((8, 8, 2), 60, np.uint16))
    with pytest.raises(InvalidArgumentError, match="^jump: "):
        synth.jump_map(an, size=64, jump=2.0)
    with pytest.raises(ValueError, match="^sample: "):
        synth.analyse(np.zeros(5))
    with pytest.raises(InvalidArgumentError, match="^sample: "):
        synth.analyse(np.full((8, 8, 3), np.nan, np.float32), textons=4, levels=1)


def test_cli_synth_writes_the_map_and_reuses_the_analysis(tmp_path, capsys):
    from btfrs.cli import main

    args = ["synth", "--size", "32", "--textons", "256", "--levels", "2", "--out-size", "80", "64",
            "--analysis", str(tmp_path / "an.btfrs"), "--out", str(tmp_path / "o"), "--quiet"]
    assert main(args) == 0
    first = np.load(tmp_path / "o" / "coords.npy")
    assert first.shape == (80, 64, 2) and first.dtype == np.uint16
    assert (tmp_path / "o" / "synthesized.png").exists() and (tmp_path / "o" / "tiled.png").exists()
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "loaded Analysis" in out and "plain tiling" in out
    np.testing.assert_array_equal(np.load(tmp_path / "o" / "coords.npy"), first)
    assert main(["synth", "--size", "32", "--textons", "5000", "--out", str(tmp_path / "p"), "--quiet",
                 "--levels", "1", "-k", "99"]) == 2


@pytest.fixture(scope="module")
def bricks():
    """A photograph-like structured sample: a 128^2 crop of brickwork that repeats every 68 x 76
    pixels, so plain tiling breaks its mortar lines and tiling at the period does not."""
    tex = btfrs.materials.texture("bricks", size=128, seed=5)
    return tex, synth.analyse(tex, textons=512, seed=0)


def _period_tiling(size, ph=68, pw=76):
    y, x = np.mgrid[0:size, 0:size]
    return np.stack([x % pw, y % ph], axis=-1).astype(np.uint16)


def _scrambled(size, n=128, block=16, seed=3):
    """16^2 blocks of the sample, each from a random place: broken structure everywhere."""
    g = np.random.default_rng(seed)
    c = np.zeros((size, size, 2), np.uint16)
    for by in range(0, size, block):
        for bx in range(0, size, block):
            sx, sy = g.integers(0, n - block, 2)
            y, x = np.mgrid[0:block, 0:block]
            c[by:by + block, bx:bx + block] = np.stack([sx + x, sy + y], -1)[:size - by, :size - bx]
    return c


def test_bricks_texture_repeats_at_its_period_only():
    t = btfrs.materials.texture("bricks", size=(150, 160), seed=2)
    assert t.shape == (150, 160, 3) and t.dtype == np.float32 and 0 <= t.min() and t.max() <= 1
    np.testing.assert_array_equal(t[:, :160 - 76], t[:, 76:])
    np.testing.assert_array_equal(t[:150 - 68], t[68:])
    assert (t[:, :32] != t[:, 128:]).any(axis=(1, 2)).all()  # a 128 tile is off the period
    assert "bricks" in btfrs.materials.texture_names()
    with pytest.raises(InvalidArgumentError, match="^period: "):
        btfrs.materials.texture("bricks", period=(3, 2))
    with pytest.raises(InvalidArgumentError, match="^name: "):
        btfrs.materials.texture("gravel")


def test_quality_ranks_brick_outputs_as_the_eye_does(bricks):
    tex, an = bricks
    size = 256
    q = lambda c: synth.quality(an, c)
    good = q(_period_tiling(size))            # seamless: the mortar lines continue
    plain = q(synth.tiled(tex.shape, size))  # broken mortar at every tile boundary
    scr = q(_scrambled(size))                 # broken everywhere
    # The good tiling copies sample windows at every scale: its seams are not seams.
    assert good.straddling > 0.05
    assert good.seam_error < 1e-6 and good.structure < 1e-6, good
    # Plain tiling's straddling windows exist nowhere in the sample; the old pair measure, the
    # user's report, called its worst seam line nearly free.
    assert plain.seam_error > 0.03 and plain.seam_error_p90 > plain.seam_error, plain
    assert plain.seam < 0.01 < plain.seam_error
    # Scrambled blocks are worse than tiling on every scale's structure and at the seams.
    assert scr.seam_error > 2 * plain.seam_error and scr.structure > 3 * plain.structure, (scr, plain)
    assert all(s > p for s, p in zip(scr.structure_levels, plain.structure_levels))
    # k-coherence leaves broken bricks (measured: structure 0.08); larger coarse neighbourhoods
    # mend part of them (paper 000, Figure 6), and both stay far from the good tiling.
    kc = q(synth.kcoherence(an, size=size, k=3, neighbourhood=2, levels=3, seed=7))
    kc4 = q(synth.kcoherence(an, size=size, k=3, neighbourhood=2, coarse_neighbourhood=4, levels=3, seed=7))
    assert kc.structure > 0.02 and kc.seam_error > 0.02, kc
    assert kc4.structure < 0.9 * kc.structure and kc4.seam_error < 0.9 * kc.seam_error, (kc4, kc)
    assert kc4.structure > 0.01 and kc4.structure < 0.5 * scr.structure
    assert str(kc).startswith("structure ")


def test_quality_of_the_sample_itself_is_zero(bricks):
    tex, an = bricks
    ident = synth.tiled(tex.shape, 128)
    q = synth.quality(an, ident)
    assert (q.structure, q.seam_error, q.seam_error_p90, q.straddling) == (0.0, 0.0, 0.0, 0.0)
    assert len(q.structure_levels) == 3
    with pytest.raises(InvalidArgumentError, match="^window: "):
        synth.quality(an, synth.tiled(tex.shape, 8))
    with pytest.raises(InvalidArgumentError, match="^coarse_neighbourhood: "):
        synth.kcoherence(an, size=64, neighbourhood=2, coarse_neighbourhood=1)
