"""The neural model: fits on every built-in material and on a single-view capture, NeuralRTI's
web format checked by an independent decoder (tests/neuralrti_reference.py, written from the
format's description), read back, and bad input named."""

from __future__ import annotations

import json
import shutil
import numpy as np
import pytest

import btfrs
from btfrs.cli import main
from btfrs.exceptions import FormatError, InvalidArgumentError

import neuralrti_reference as ref

# Without a horizon map: these tests count the plain form's bytes and inputs (the horizon's
# own tests below name it).
QUICK = dict(latents=4, hidden=16, features=4, steps=400, horizon=0)


@pytest.mark.parametrize("name", btfrs.materials.names())
def test_fits_every_material_and_beats_its_mean(name):
    # 400 steps on 16^2: far from converged, but the fit must explain much of the texture's
    # variation beyond the per-pair mean image (a model that ignored its latents would not).
    btf = btfrs.materials.make(name, size=16, seed=2)
    train, test = btf.split(holdout=0.1, seed=1)
    m = btfrs.fit.neural(train, **QUICK)
    assert isinstance(m, btfrs.Neural) and m.directions == "half" and m.activation == "relu"
    err = m.error(test).relative
    mean = btf.data.mean(axis=(0, 1), keepdims=True)
    mask = ~train.mask if train.mask is not None else np.ones(btf.data.shape[2:4], bool)
    gt = btf.data[:, :, mask]
    base = np.linalg.norm(np.broadcast_to(mean, btf.data.shape)[:, :, mask] - gt) / np.linalg.norm(gt)
    assert np.isfinite(err) and err < 0.9 * base, (name, err, base)
    r = m.report
    assert r["steps"] <= 400 and r["qat_steps"] >= 1 and r["validation_pairs"] > 0
    assert m.latents.shape == (16, 16, 4)
    # nbytes: the latent bytes, their scales and biases, and the decoder as the renderer holds
    # it, half-precision values: the dense layers' rows padded to vectors of eight (4 latents +
    # 6 coordinates + 3 x 4 features = 22 inputs -> 24; 16 units; 3 outputs), the direction
    # tables (3 x 8 x 8 nodes of 4 features).
    dense = 16 * 24 + 16 + 16 * 16 + 16 + 3 * 16 + 8
    assert m.nbytes == 16 * 16 * 4 + 8 * 4 + 2 * (dense + 3 * 64 * 4)
    # Every decoder parameter is a half (the output layer's times a power of two).
    d = m.arrays["decoder"]
    assert d.size == 16 * 22 + 16 + 16 * 16 + 16 + 3 * 16 + 3 + 3 * 64 * 4
    plain = np.r_[d[: 16 * 22 + 16 + 16 * 16 + 16], d[-3 * 64 * 4 :]]  # all but the output layer
    assert np.array_equal(plain.astype(np.float16).astype(np.float32), plain)


def _capture(size=16, seed=3):
    """A built-in material seen from above under its 81 lights: a single-view RTI capture."""
    return btfrs.materials.make("bumps", size=size, seed=seed, views=[[0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def rti_model():
    # NeuralRTI's exact form, which has no horizon map (the export refuses one).
    return btfrs.fit.neural(_capture(), latents=8, hidden=20, steps=600, horizon=0)


def test_single_view_is_neuralrti_form(rti_model):
    m = rti_model
    assert m.directions == "light" and m.activation == "elu"
    (w1, _), (w2, _), (w3, _) = m.layers
    assert w1.shape == (20, 8 + 2) and w2.shape == (20, 20) and w3.shape == (3, 20)


def _apply_layers(m, view, light):
    """The model's prediction from its published parts alone (``latents``, ``layers``,
    ``tables``), in float64 numpy: the encoding written from the docstrings, bilinear table
    lookups over the elevated concentric square."""
    v, l = np.asarray(view, float), np.asarray(light, float)
    h = (v + l) / np.linalg.norm(v + l)
    coords = {"light": [l[:2]], "xy": [v[:2], l[:2]], "half": [v[:2], l[:2], h[:2]]}[m.directions]
    dirs = {"light": [l], "xy": [v, l], "half": [v, l, h]}[m.directions]
    enc = list(np.concatenate(coords))
    hz = m.horizon
    if hz is not None:
        clear_dirs = [l] if m.directions == "light" else [v, l]
        bins = hz.shape[-1]
        clear = []
        for d in clear_dirs:
            f = (np.arctan2(d[1], d[0]) % (2 * np.pi)) / (2 * np.pi) * bins
            k0 = int(np.floor(f)) % bins
            w = f - np.floor(f)
            row = hz[:, :, k0] * (1 - w) + hz[:, :, (k0 + 1) % bins] * w
            clear.append(np.arcsin(np.clip(d[2], -1, 1)) - row)
    tables = m.tables.astype(np.float64)
    g = tables.shape[1]
    for t in range(tables.shape[0]):
        s_, t_ = btfrs.hemimap.hemisphere_to_square(dirs[t]) * (g - 1)
        i, j = min(int(np.floor(s_)), g - 2), min(int(np.floor(t_)), g - 2)
        fx, fy = s_ - i, t_ - j
        f = ((1 - fx) * (1 - fy) * tables[t, j, i] + fx * (1 - fy) * tables[t, j, i + 1]
             + (1 - fx) * fy * tables[t, j + 1, i] + fx * fy * tables[t, j + 1, i + 1])
        enc += list(f)
    z = m.latents.astype(np.float64)
    nd = len(np.concatenate(coords))
    parts = [z, np.broadcast_to(np.array(enc[:nd]), z.shape[:2] + (nd,))]
    if hz is not None:
        parts.append(np.stack(clear, -1).astype(np.float64))
    parts.append(np.broadcast_to(np.array(enc[nd:]), z.shape[:2] + (len(enc) - nd,)))
    x = np.concatenate(parts, axis=-1)
    act = (lambda a: np.maximum(a, 0)) if m.activation == "relu" else (lambda a: np.where(a > 0, a, np.expm1(a)))
    (w1, b1), (w2, b2), (w3, b3) = [(w.astype(np.float64), b.astype(np.float64)) for w, b in m.layers]
    y = act(act(x @ w1.T + b1) @ w2.T + b2) @ w3.T + b3
    return y * (1.0 if m.directions == "light" else max(l[2], 0.0))


@pytest.mark.parametrize("form", ["half", "xy", "light"])
@pytest.mark.parametrize("horizon", [0, 5])
def test_layers_and_tables_reproduce_evaluate(form, horizon):
    # The published parts must be the whole decoder: every parameter used once, and applied in
    # numpy they give what the model evaluates, on a multi-view model (with tables) as on the
    # single-view form, with and without a horizon map (NeuralRTI's form has none).
    if form == "light":
        btf, opts = _capture(size=8), dict(latents=5, hidden=12, steps=150)
    else:
        btf, opts = btfrs.materials.make("knit", size=8, seed=1), dict(latents=6, hidden=12, features=5, directions=form, steps=150)
    m = btfrs.fit.neural(btf, horizon=horizon, **opts)
    assert m.directions == form
    assert (m.horizon is None) == (horizon == 0)
    used = sum(w.size + b.size for w, b in m.layers) + m.tables.size
    assert used == m.arrays["decoder"].size
    (w1, _), _, _ = m.layers
    tables = {"half": 3, "xy": 2, "light": 0}[form]
    coords = {"half": 6, "xy": 4, "light": 2}[form]
    clear = 0 if horizon == 0 else (1 if form == "light" else 2)
    assert w1.shape == (12, opts["latents"] + coords + clear + tables * opts.get("features", 0))
    assert m.tables.shape[0] == tables
    for view, light in (([0, 0, 1], [0.3, 0.2, 0.93]), ([0.5, -0.2, 0.84], [-0.6, 0.3, 0.74])):
        if form == "light":
            view = [0, 0, 1]
        v = np.array(view, float) / np.linalg.norm(view)
        l_ = np.array(light, float) / np.linalg.norm(light)
        want = m.evaluate(view=v, light=l_).astype(np.float64)
        got = _apply_layers(m, v, l_)
        scale = np.abs(want).max()
        assert scale > 0 and np.abs(got - want).max() <= 1e-4 * scale, (form, np.abs(got - want).max(), scale)


def test_neuralrti_export_decodes_to_evaluate_by_an_independent_decoder(rti_model, tmp_path):
    m = rti_model
    out = tmp_path / "web"
    res = m.export(out, format="neuralrti")
    info = json.loads((out / "info.json").read_text())
    assert info["type"] == "neural" and info["planes"] == 9 and info["colorspace"] == "bgr"
    assert len(info["weights"][0]) == 20 * 12 and info["samples"] == 20  # [out][in], padded to 4
    assert {f"plane_{i}.jpg" for i in (1, 2, 3)} <= set(res["files"])
    lossless = tmp_path / "png"
    shutil.copytree(out, lossless)
    for p in lossless.glob("*.jpg"):
        p.unlink()
    for light in ([0.0, 0.0, 1.0], [0.5, -0.3, 0.81], [-0.7, 0.2, 0.68]):
        light = np.asarray(light) / np.linalg.norm(light)
        want = m.evaluate([0, 0, 1], light).astype(np.float64)
        got = ref.decode(str(lossless), (light[0], light[1]))
        # The PNG planes are the model's bytes: equal to float32 rounding.
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5 * np.abs(want).max())
        assert np.abs(ref.to_bytes(got).astype(int) - ref.to_bytes(want).astype(int)).max() <= 1
        # The JPEG planes OpenLIME loads: within a few 8-bit steps of the model's display bytes.
        jpg = ref.to_bytes(ref.decode(str(out), (light[0], light[1]))).astype(int)
        assert np.mean(np.abs(jpg - ref.to_bytes(want).astype(int))) < 3.0


def test_neuralrti_folder_reads_back_as_the_same_model(rti_model, tmp_path):
    m = rti_model
    m.export(tmp_path / "web", format="neuralrti")
    back = btfrs.io.load(tmp_path / "web" / "info.json")
    assert isinstance(back, btfrs.Neural) and back.directions == "light"
    for light in ([0.3, 0.3, 0.9], [-0.6, 0.0, 0.8]):
        np.testing.assert_allclose(back.evaluate([0, 0, 1], light), m.evaluate([0, 0, 1], light), rtol=1e-5, atol=1e-6)


def test_export_refuses_a_model_not_in_neuralrti_form(tmp_path):
    m = btfrs.fit.neural(btfrs.materials.make("weave", size=8, seed=1), **QUICK)
    with pytest.raises(InvalidArgumentError, match=r"^format: NeuralRTI's form .*directions=\"light\""):
        m.export(tmp_path / "x", format="neuralrti")
    assert not (tmp_path / "x").exists()


def test_broken_neuralrti_files_are_named(rti_model, tmp_path):
    rti_model.export(tmp_path / "w", format="neuralrti")
    info = json.loads((tmp_path / "w" / "info.json").read_text())
    info["weights"][1] = info["weights"][1][:-4]
    (tmp_path / "w" / "info.json").write_text(json.dumps(info))
    with pytest.raises(FormatError, match=r"info.json: weights: expected 20 x 12, 20 x 20 and 3 x 20 values"):
        btfrs.io.load(tmp_path / "w" / "info.json")
    info["weights"][1] = ["x"] * 400
    (tmp_path / "w" / "info.json").write_text(json.dumps(info))
    with pytest.raises(FormatError, match=r"weights\[1\]: \"x\" is not a finite number"):
        btfrs.io.load(tmp_path / "w" / "info.json")


def test_saved_model_with_mismatched_weights_is_refused(rti_model, tmp_path):
    a = rti_model.arrays
    a["decoder"] = a["decoder"][:-1]
    with pytest.raises(FormatError, match="decoder.*expected .* decoder parameters"):
        btfrs.Neural.from_arrays(a)
    a = rti_model.arrays
    a["decoder"][3] = np.inf
    with pytest.raises(FormatError, match="decoder parameter 3 .* not finite"):
        btfrs.Neural.from_arrays(a)


def test_too_few_pairs_for_the_latents_is_named():
    btf = btfrs.materials.make("bumps", size=8, seed=1)
    mask = np.zeros((81, 81), bool)
    mask[0, :6] = True
    with pytest.raises(InvalidArgumentError, match=r"^latents: expected at most as many latents as training pairs"):
        btfrs.fit.neural(btfrs.Btf(btf.data, btf.views, btf.lights, mask=mask), latents=8)


def test_cli_fits_a_neural_model(tmp_path):
    out = tmp_path / "n.btfrs"
    assert main(["fit", "--material", "grooves", "--size", "8", "--model", "neural", "--quiet",
                 "--set", "steps=200", "--set", "hidden=8", "-o", str(out)]) == 0
    m = btfrs.load(out)
    assert isinstance(m, btfrs.Neural) and m.report["steps"] <= 200


def psnr(a, b):
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    peak = float(max(a.max(), b.max()))
    return np.inf if mse == 0 else 10 * np.log10(peak * peak / mse)


def test_gpu_matches_the_cpu_reference_on_every_scene_and_with_a_coordinate_map():
    btf = btfrs.materials.make("weave", size=16, seed=2)
    m = btfrs.fit.neural(btf, **QUICK)
    cam = btfrs.Camera.look_at([0, -3, 2], [0, 0, 0], 40)
    lights = [btfrs.PointLight([2, -2, 3], 8.0), btfrs.DirectionalLight([-1, -0.5, 1], [0.4, 0.3, 0.2])]
    yy, xx = np.mgrid[0:48, 0:48]
    cmap = np.stack([(xx * 5 + 1) % 16, (yy * 3) % 16], -1).astype(np.uint16)
    for scene in (btfrs.Scene.plane(), btfrs.Scene.sphere(), btfrs.Scene.cylinder()):
        for coords in (None, cmap):
            kw = dict(size=(48, 64), uv_scale=2.0, coords=coords)
            g = btfrs.render(m, scene, cam, lights, **kw)
            c = btfrs.render(m, scene, cam, lights, backend="cpu", **kw)
            assert (c.sum(-1) > 0).mean() > 0.2
            assert psnr(g, c) >= 40, psnr(g, c)
    # The single-view form (ELU, the light only) draws the same on both.
    r = btfrs.fit.neural(_capture(size=8), latents=3, hidden=8, steps=100)
    g = btfrs.render(r, btfrs.Scene.plane(), cam, lights, size=48)
    c = btfrs.render(r, btfrs.Scene.plane(), cam, lights, size=48, backend="cpu")
    assert psnr(g, c) >= 40
    # The shader's layout edges: the largest decoder (its weights fill the uniform block), an
    # odd feature count (a padded half per table node), a hidden width not a multiple of 8.
    for shape in (dict(latents=32, hidden=64, features=15), dict(latents=5, hidden=12, features=3)):
        e = btfrs.fit.neural(btf, steps=30, **shape)
        g = btfrs.render(e, btfrs.Scene.sphere(), cam, lights, size=48)
        c = btfrs.render(e, btfrs.Scene.sphere(), cam, lights, size=48, backend="cpu")
        assert (c.sum(-1) > 0).mean() > 0.2
        assert psnr(g, c) >= 40, (shape, psnr(g, c))


def test_cli_exports_neuralrti_into_a_folder(rti_model, tmp_path, capsys):
    src = tmp_path / "m.btfrs"
    rti_model.save(src)
    assert main(["export", "--quiet", "--neuralrti", str(tmp_path / "web"), str(src)]) == 0
    assert "wrote" in capsys.readouterr().out
    back = btfrs.io.load(tmp_path / "web" / "info.json")
    np.testing.assert_allclose(back.evaluate([0, 0, 1], [0.2, 0.1, 0.97]), rti_model.evaluate([0, 0, 1], [0.2, 0.1, 0.97]),
                               rtol=1e-5, atol=1e-6)
    # A file where the folder should be is refused before any work.
    (tmp_path / "file").write_text("x")
    assert main(["export", "--quiet", "--neuralrti", str(tmp_path / "file"), str(src)]) != 0
    assert "is a file; expected a folder" in capsys.readouterr().err


def test_environment_light_by_sampling_converges_to_the_quadrature():
    # The sampled environment (importance sampling of the sky) against its quadrature, both
    # through the neural shader on the GPU and the CPU reference.
    btf = btfrs.materials.make("bumps", size=16, seed=2)
    m = btfrs.fit.neural(btf, **QUICK)
    sky = btfrs.Environment.sky(sun=[0.4, -0.5, 0.75], turbidity=3, height=16)
    scene, cam = btfrs.Scene.sphere(), btfrs.Camera.look_at([0, -3, 2], [0, 0, 0], 40)
    ref = btfrs.render(m, scene, cam, sky.quadrature(), size=(32, 40), backend="cpu")
    gpu_ref = btfrs.render(m, scene, cam, sky.quadrature(), size=(32, 40))
    assert psnr(gpu_ref, ref) >= 40
    errs = []
    for n in (16, 256):
        sampled = btfrs.render(m, scene, cam, environment=sky, samples=n, seed=1, size=(32, 40))
        errs.append(float(np.sqrt(np.mean((sampled - ref) ** 2)) / np.sqrt(np.mean(ref ** 2))))
    assert errs[1] < 0.03 and errs[0] > 2 * errs[1], errs


def test_fits_a_capture_file_and_the_cli_fits_it_too(tmp_path):
    # A single-view capture written as an image stack (8-bit PNG + directions table), loaded as
    # a user's capture is: the fit takes NeuralRTI's form and explains it.
    cap = _capture(size=16, seed=5)
    table = btfrs.io.save_stack(cap, tmp_path / "stack", format="png")
    btf = btfrs.io.load(tmp_path / "stack", directions=table)
    assert btf.n_views == 1 and btf.n_lights == 81
    train, test = btf.split(holdout=0.2, seed=0)
    m = btfrs.fit.neural(train, latents=6, hidden=16, steps=800)
    assert m.directions == "light" and m.activation == "elu"
    # Far better than the texture's mean image under each held-out light.
    held = ~train.mask
    gt = btf.data[:, :, held]
    base = np.linalg.norm(gt.mean(axis=(0, 1), keepdims=True) - gt) / np.linalg.norm(gt)
    assert m.error(test).relative < 0.6 * base, (m.error(test), base)
    out = tmp_path / "cap.btfrs"
    assert main(["fit", str(tmp_path / "stack"), "--directions", table, "--model", "neural", "--quiet",
                 "--set", "steps=200", "--set", "hidden=8", "-o", str(out)]) == 0
    assert btfrs.load(out).directions == "light"


def test_a_capture_above_train_texels_trains_on_a_sample_and_encodes_the_rest():
    # 20^2 texels, a sample of 192 (three runs of 64, spread over the image), with the horizon
    # map: the encoder gives the other texels their codes. At unseen lights the model must stay
    # close to the same fit trained on every texel.
    cap = _capture(size=20)
    held = list(range(4, 81, 9))
    train = cap.select(lights=[i for i in range(81) if i not in held])
    test = cap.select(lights=held)
    opts = dict(latents=6, hidden=16, steps=500, seed=1)
    sampled = btfrs.fit.neural(train, train_texels=192, **opts)
    full = btfrs.fit.neural(train, **opts)
    r = sampled.report
    assert r["sample_texels"] == 192 and "sample_texels" not in full.report
    assert r["horizon"] > 0 and r["encoder"]["reconstruction_steps"] > 0
    assert r["encoder"]["error"] <= r["encoder"]["error_after_regression"]
    es, ef = sampled.error(test).relative, full.error(test).relative
    assert es < 1.25 * ef, (es, ef)
    assert sampled.latents.shape == (20, 20, 6)
    with pytest.raises(InvalidArgumentError, match="^train_texels: expected"):
        btfrs.fit.neural(train, train_texels=0)
