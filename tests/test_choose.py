"""btfrs.choose: the scene's directions against closed forms, the numpy interpolation against the
CPU renderer, and the issue's known-answer cases."""

from __future__ import annotations

import json

import numpy as np
import pytest

import btfrs
from btfrs.choosing import _raw_image, interp_weights


def top_camera(d: float, fov: float) -> btfrs.Camera:
    return btfrs.Camera.look_at([0.0, 0.0, d], [0.0, 0.0, 0.0], fov)


def test_scene_directions_of_a_plane_from_above_in_closed_form():
    # A plane of side 1 seen from height d = 2 with a 90 degree field of view: the image spans
    # [-2, 2] at z = 0, so the plane covers (64 / 4)^2 = 256 of the 64^2 pixels. The plane's
    # frame is the world's, so a directional light's local direction is its own direction, and
    # the view at pixel centre (x, y) is normalize(eye - p) exactly.
    light_dir = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
    use = btfrs.SceneUse(camera=top_camera(2.0, 90.0), lights=[btfrs.DirectionalLight(light_dir, 2.0)],
                         size=(64, 64), scene=btfrs.Scene.plane(1.0), uv_scale=2.0)
    d = use.directions((16, 16))
    assert d["pixels"] == [256] and len(d["views"]) == 256
    np.testing.assert_allclose(d["lights"], np.tile(light_dir, (256, 1)), atol=1e-6)
    np.testing.assert_allclose(d["weights"], 2.0)
    centre = np.argmax(d["views"][:, 2])
    assert d["views"][centre, 2] > 0.999
    # Footprint: 2 repetitions x 16 texels over 16 pixels = 2 texels per pixel.
    np.testing.assert_allclose(d["footprint"], 2.0, atol=1e-3)
    # The view directions against the pixel-centre rays, independently.
    raw = btfrs._native.scene_directions(use.scene, use.cameras[0], [x._native() for x in use.light_sets[0]], 64, 64,
                                         [2.0, 2.0], (16, 16))
    px, py = raw["pixels"] % 64 + 0.5, raw["pixels"] // 64 + 0.5
    world = np.stack([(px / 64 * 2 - 1) * 2.0, (1 - py / 64 * 2) * 2.0, np.zeros_like(px)], axis=1)
    expect = np.array([0.0, 0.0, 2.0]) - world
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    np.testing.assert_allclose(raw["views"], expect, atol=1e-4)


def test_light_sets_and_camera_paths_split_the_weight():
    lights = [[btfrs.DirectionalLight([0, 0, 1], 1.0)], [btfrs.DirectionalLight([0.5, 0, 1], 1.0)]]
    cams = [top_camera(2.0, 90.0), top_camera(2.5, 90.0)]
    use = btfrs.SceneUse(camera=cams, lights=lights, size=32, scene=btfrs.Scene.plane(1.0))
    d = use.directions((16, 16))
    assert use.frames == 4 and len(d["pixels"]) == 2
    # Every (frame, pixel) counts once: the weights sum to the mean covered pixel count.
    assert d["weights"].sum() == pytest.approx(sum(d["pixels"]) / 2)


def test_numpy_interpolation_matches_the_cpu_raw_renderer():
    # The score's reference (numpy interpolation, choosing.interp_weights) against the Rust raw
    # renderer: a plane under a directional light of irradiance 1, every pixel's value is the
    # raw interpolation at its own (view, light) at the texel it sees.
    btf = btfrs.materials.make("bumps", size=16, seed=3)
    cam = btfrs.Camera.look_at([0.4, -0.9, 1.6], [0, 0, 0], 50)
    light = btfrs.DirectionalLight([0.2, 0.5, 0.8], 1.0)
    img = btfrs.render(btf, btfrs.Scene.plane(2.0), cam, [light], size=(48, 48), backend="cpu")
    d = btfrs._native.scene_directions(btfrs.Scene.plane(2.0), cam, [light._native()], 48, 48, [1.0, 1.0], (16, 16))
    rng = np.random.default_rng(0)
    for k in rng.choice(len(d["pixels"]), 25, replace=False):
        p = int(d["pixels"][k])
        u, v = d["uv"][k]
        col = min(int((u - np.floor(u)) * 16), 15)
        row = min(int((1 - (v - np.floor(v))) * 16), 15)
        ref = _raw_image(btf, d["views"][k].astype(np.float64), d["lights"][k, 0].astype(np.float64))
        np.testing.assert_allclose(img[p // 48, p % 48], ref[row, col], rtol=2e-3, atol=1e-5)


def test_interp_weights_mirror_the_rust_rule():
    dirs = btfrs.directions.ubo81()
    idx, w = interp_weights(dirs, dirs[[17, 40]])
    assert idx[0, 0] == 17 and w[0, 0] == 1.0 and w[0, 1:].sum() == 0.0
    q = np.array([[0.1, 0.2, 0.97]]) / np.linalg.norm([0.1, 0.2, 0.97])
    idx, w = interp_weights(dirs, q)
    ang = np.arccos(np.clip(dirs @ q[0], -1, 1))
    near = np.argsort(ang)
    assert list(idx[0]) == list(near[:3])
    expect = 1 / ang[near[:3]] - 1 / ang[near[3]]
    np.testing.assert_allclose(w[0], expect / expect.sum(), rtol=1e-9)


# Few, fast candidates (no multi-lobe Lafortune: seconds per fit); every kind of answer is among
# them: a global model (Phong+SRF), per-view-slot ones (PTM), a clustered basis whose size follows
# the directions it is fitted on (LPCA) and the raw data of the used slots.
FAST = [("srf", "Phong+SRF", {}), ("ptm", "PTM-LRGB", {"kind": "lrgb"}),
        ("lpca", "LPCA 8x4", {"clusters": 8, "components": 4}), ("raw", "raw data", {})]


def ring_of_lights(theta: float, n: int) -> list:
    return [[btfrs.DirectionalLight(btfrs.directions.from_theta_phi(theta, a, degrees=True), 1.0)]
            for a in np.arange(0, 360, 360 / n)]


def row(pick, label: str, subset: str) -> dict:
    return next(c for c in pick.candidates if c["label"] == label and c["subset"] == subset)


def test_fixed_top_view_under_moving_lights_picks_a_few_slot_model():
    # A distant camera straight above sees the plane within 10 degrees of the normal: the top
    # view slot and its 15-degree ring (7 of 81), and the 8 lights of a 40-degree ring touch
    # their 3 nearest measured lights each. A model fitted on those slots meets the tolerance at
    # a small fraction of the same model fitted on everything.
    btf = btfrs.materials.make("weave", size=16, seed=1)
    use = btfrs.SceneUse(camera=top_camera(6.0, 15.0), lights=ring_of_lights(40, 8), size=(48, 48),
                         scene=btfrs.Scene.plane(2.0))
    pick = btfrs.choose(btf, scene=use, tolerance=0.05, candidates=FAST, measure_render=False, seed=0)
    assert len(pick.views_used) == 7 and 0 in pick.views_used
    assert len(pick.lights_used) <= 24
    assert pick.met and pick.error <= 0.05
    assert pick.subset == "scene"
    full = row(pick, pick.label, "full")
    assert pick.nbytes * 10 < full["nbytes"], (pick.nbytes, full["nbytes"])
    # Every cheaper candidate really misses the tolerance.
    for c in pick.candidates:
        if c["nbytes"] is not None and c["nbytes"] < pick.nbytes:
            assert c["error"] > 0.05, c
    text = pick.explain()
    assert "7 of 81 views" in text and "(chosen)" in text and pick.label in text
    assert pick.to_dict()["views_used"] == [int(v) for v in pick.views_used]


def test_moving_camera_over_a_glossy_material_needs_every_view():
    # A camera path around the sphere sees every view slot; the glossy knit under a point light
    # then has no few-slot answer: what meets the tolerance is fitted on all 81 views.
    btf = btfrs.materials.make("knit", size=16, seed=1)
    cams = [btfrs.Camera.look_at([3 * np.cos(a), 3 * np.sin(a), 1.5], [0, 0, 0], 40)
            for a in np.radians(np.arange(0, 360, 45))]
    use = btfrs.SceneUse(camera=cams, lights=[btfrs.PointLight([2, -2, 3], 8.0)], size=(48, 48),
                         scene=btfrs.Scene.sphere(1.0, 32, 16))
    pick = btfrs.choose(btf, scene=use, tolerance=0.15, candidates=FAST, measure_render=False, seed=0)
    assert len(pick.views_used) == 81
    assert pick.met
    assert row(pick, pick.label, pick.subset)["views"] == 81
    # The same fixed-top-view question on this material would need 7.
    top = btfrs.choose(btf, scene=btfrs.SceneUse(camera=top_camera(6.0, 15.0), lights=ring_of_lights(40, 8),
                                                 size=(48, 48), scene=btfrs.Scene.plane(2.0)),
                       tolerance=0.15, candidates=FAST[:2], subsets=["scene"], measure_render=False)
    assert len(top.views_used) == 7 and row(top, top.label, "scene")["views"] == 7


def test_an_impossible_tolerance_returns_the_best_available_flagged():
    btf = btfrs.materials.make("weave", size=16, seed=1)
    use = btfrs.SceneUse(camera=top_camera(6.0, 15.0), lights=ring_of_lights(40, 8), size=(32, 32),
                         scene=btfrs.Scene.plane(2.0))
    # The raw data of the used slots is over the byte budget; no model comes within 1e-6.
    pick = btfrs.choose(btf, scene=use, tolerance=1e-6, budget_bytes=200_000, candidates=FAST,
                        measure_render=False)
    assert not pick.met
    within = [c for c in pick.candidates if c["nbytes"] is not None and c["nbytes"] <= 200_000]
    assert pick.error == min(c["error"] for c in within)
    assert pick.nbytes <= 200_000
    text = pick.explain()
    assert "NOT MET" in text and "best available" in text
    assert any("over the byte budget" in c["status"] for c in pick.candidates)


def test_mip_level_follows_the_texel_footprint():
    # The plane (side 2) seen from 6 units with a 40 degree field of view spans
    # 64 * 2 / (2 * 6 * tan 20) = 29.3 pixels; 8 repetitions of 16 texels put 4.37 texels in a
    # pixel: mip level floor(log2 4.37) = 2. One repetition: 0.55 texels, level 0.
    btf = btfrs.materials.make("weave", size=16, seed=1)
    light = btfrs.DirectionalLight([0.2, 0.1, 1.0], 1.0)
    errors = {}
    for uv_scale, level in [(8.0, 2), (1.0, 0)]:
        use = btfrs.SceneUse(camera=top_camera(6.0, 40.0), lights=light, size=64, scene=btfrs.Scene.plane(2.0),
                             uv_scale=uv_scale)
        pick = btfrs.choose(btf, scene=use, tolerance=0.5, candidates=FAST[:1], subsets=["full"],
                            measure_render=False)
        assert pick.mip_level == level
        errors[level] = pick.error
    # The same directions (uv_scale moves no direction): seen coarser, the per-texel detail a
    # global model misses averages out, and the error is smaller.
    assert errors[2] < 0.8 * errors[0], errors
    json.dumps(pick.to_dict())


def test_render_time_is_measured_and_the_choice_renders():
    btf = btfrs.materials.make("weave", size=16, seed=1)
    use = btfrs.SceneUse(camera=top_camera(6.0, 15.0), lights=ring_of_lights(40, 4), size=(32, 32),
                         scene=btfrs.Scene.plane(2.0))
    seen = []
    # LPCA 8x4 meets 0.04 on these slots (0.032), PTM-LRGB does not (0.054).
    pick = btfrs.choose(btf, scene=use, tolerance=0.04, candidates=FAST[1:3], subsets=["scene"],
                        progress=lambda d, t: seen.append((d, t)))
    assert seen[-1][0] == seen[-1][1] == 2
    # Timed: the candidates that can be chosen, and only those.
    assert {c["label"]: np.isfinite(c["render_ms"]) for c in pick.candidates} == {"LPCA 8x4": True, "PTM-LRGB": False}
    assert pick.label == "LPCA 8x4" and pick.render_ms > 0
    img = btfrs.render(pick.model, use.scene, use.cameras[0], list(use.light_sets[0]), size=(32, 32))
    assert img.shape == (32, 32, 3) and img.max() > 0
    # A budget on time that nothing meets is reported as such.
    slow = btfrs.choose(btf, scene=use, tolerance=0.2, candidates=FAST[1:3], subsets=["scene"], budget_ms=1e-6)
    assert not slow.met and all("time budget" in c["status"] for c in slow.candidates)


def test_bad_arguments_name_themselves():
    cam = top_camera(3.0, 40.0)
    light = btfrs.DirectionalLight([0, 0, 1], 1.0)
    with pytest.raises(btfrs.ArgumentTypeError, match="camera"):
        btfrs.SceneUse(camera="top", lights=[light])
    with pytest.raises(btfrs.InvalidArgumentError, match="camera"):
        btfrs.SceneUse(camera=[], lights=[light])
    with pytest.raises(btfrs.ArgumentTypeError, match=r"lights\[1\]\[0\]"):
        btfrs.SceneUse(camera=cam, lights=[[light], [3]])
    with pytest.raises(btfrs.InvalidArgumentError, match="lights"):
        btfrs.SceneUse(camera=cam, lights=[])
    with pytest.raises(btfrs.InvalidArgumentError, match="size"):
        btfrs.SceneUse(camera=cam, lights=light, size=0)
    with pytest.raises(btfrs.InvalidArgumentError, match="uv_scale"):
        btfrs.SceneUse(camera=cam, lights=light, uv_scale=-1)
    with pytest.raises(btfrs.ArgumentTypeError, match="scene"):
        btfrs.SceneUse(camera=cam, lights=light, scene="plane")
    btf = btfrs.materials.make("weave", size=16, seed=1)
    use = btfrs.SceneUse(camera=cam, lights=light, size=16)
    with pytest.raises(btfrs.InvalidArgumentError, match="tolerance"):
        btfrs.choose(btf, scene=use, tolerance=0)
    with pytest.raises(btfrs.ArgumentTypeError, match="scene"):
        btfrs.choose(btf, scene=cam)
    with pytest.raises(btfrs.InvalidArgumentError, match="candidates"):
        btfrs.choose(btf, scene=use, candidates=[("nope", "x", {})])
    with pytest.raises(btfrs.InvalidArgumentError, match="subsets"):
        btfrs.choose(btf, scene=use, subsets=["all"])
    with pytest.raises(btfrs.InvalidArgumentError, match="budget_bytes"):
        btfrs.choose(btf, scene=use, budget_bytes=0)
    with pytest.raises(btfrs.InvalidArgumentError, match="budget_bytes.*'8 apples'"):
        btfrs.choose(btf, scene=use, budget_bytes="8 apples")
    train, _ = btf.split(holdout=0.1, seed=0)
    with pytest.raises(btfrs.InvalidArgumentError, match="btf"):
        btfrs.choose(train, scene=use)
    away = btfrs.SceneUse(camera=btfrs.Camera.look_at([0, 0, -3], [0, 0, 5], 40), lights=light, size=16)
    with pytest.raises(btfrs.InvalidArgumentError, match="scene"):
        btfrs.choose(btf, scene=away, measure_render=False)


def test_command_line(capsys):
    from btfrs.cli import main

    rc = main(["choose", "--material", "weave", "--size", "16", "--camera", "0", "0", "6", "--fov", "15",
               "--light", "0.64", "0", "0.77", "--light", "-0.64", "0", "0.77", "--image-size", "32", "32",
               "--kinds", "ptm", "raw", "--tolerance", "0.1", "--no-render", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0 and "scene uses 7 of 81 views" in out and "chosen:" in out and "PTM-RGB" in out
    # Two lights touch 6 measured lights: just enough for a PTM per slot (the default
    # on_degenerate="reduce" would fit a plane to fewer), so the PTM on the scene's 7 x 6 slots
    # is a candidate, meets the tolerance and beats the raw data of the same slots on bytes.
    import re

    assert "failed" not in out
    m = re.search(r"^\* (PTM-\w+) +scene +7x6 +([\d.]+) +(\d+)", out, re.M)
    assert m and float(m.group(2)) <= 0.1, out
    raw = re.search(r"^  raw data +scene +7x6 +[\d.]+ +(\d+)", out, re.M)
    assert raw and int(m.group(3)) < int(raw.group(1))
    rc = main(["choose", "--size", "16", "--kinds", "nope", "--quiet"])
    assert rc == 2 and "--kinds" in capsys.readouterr().err


def test_the_documented_choice():
    # docs/choosing.md states the decision for a 32² weave under 8 lights on a 40-degree ring,
    # 512² frames, with every registered model as a candidate (scripts/choose_examples.py, a
    # minute); with the fast candidates the winner and its size are the same.
    from pathlib import Path

    btf = btfrs.materials.make("weave", size=32, seed=2)
    cam = btfrs.Camera.look_at([0, 0, 6], [0, 0, 0], 15)
    lights = [[btfrs.DirectionalLight(btfrs.directions.from_theta_phi(40, a, degrees=True))]
              for a in range(0, 360, 45)]
    use = btfrs.SceneUse(camera=cam, lights=lights, size=(512, 512), scene=btfrs.Scene.plane(2.0), uv_scale=2)
    # The budget as the docs write it: a size string, read as its bytes.
    pick = btfrs.choose(btf, scene=use, tolerance=0.05, budget_bytes="8MiB", candidates=FAST, measure_render=False)
    assert pick.budget_bytes == 8 << 20
    assert (pick.label, pick.subset, pick.nbytes, len(pick.views_used), len(pick.lights_used)) == \
        ("LPCA 8x4", "scene", 52384, 7, 23)
    text = (Path(__file__).resolve().parents[1] / "docs" / "choosing.md").read_text()
    assert "uses 7 of 81 views and 23 of 81 lights, and the choice is LPCA 8 x 4 fitted on those 7 x 23 " \
        "slots, 52,384 bytes" in " ".join(text.split())


def dome(n: int, lo: float = 12.0, hi: float = 85.0) -> np.ndarray:
    el = np.radians(lo + (hi - lo) * np.arange(n) / (n - 1))
    az = 2.399963 * np.arange(n)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)


def test_without_a_scene_the_smallest_model_meeting_the_held_out_tolerance():
    # A single-view capture and the RTI question: which model predicts the lights not
    # photographed? Each candidate's held-out error is recomputed here in float64 numpy from a
    # fresh fit on the kept lights; the choice is the smallest that meets the tolerance.
    cap = btfrs.materials.make("bumps", size=16, seed=3, views=[[0.0, 0.0, 1.0]], lights=dome(30))
    cands = [("ptm", "PTM-RGB", {"kind": "rgb"}), ("hsh", "HSH-3", {"order": 3}),
             ("rbf", "RBF-18", {"components": 18}), ("neural", "Neural-8", {"latents": 8, "steps": 400}),
             ("raw", "raw data", {})]
    first = btfrs.choose(cap, tolerance=1.0, candidates=cands, holdout=0.2, seed=5)
    assert len(first.lights_held) == 6 and len(first.lights_used) == 24
    assert not set(first.lights_held) & set(first.lights_used)
    kept = cap.select(lights=first.lights_used)
    held = cap.select(lights=first.lights_held)
    truth = held.data[:, :, 0].astype(np.float64)
    errors = {}
    for c in first.candidates:
        assert c["fit_s"] is not None and c["fit_s"] >= 0 and c["subset"] == "kept", c
        if c["kind"] == "raw":
            continue
        m = btfrs.fit.fit(c["kind"], kept, **c["options"])
        pred = np.stack([m.evaluate(held.views[0], held.lights[j]) for j in range(held.n_lights)], 2)
        errors[c["label"]] = float(np.linalg.norm(pred - truth) / np.linalg.norm(truth))
        assert c["error"] == pytest.approx(errors[c["label"]], rel=1e-4), c
    # A tolerance between the errors: the choice is the smallest candidate at or under it.
    tol = float(np.median(list(errors.values())))
    pick = btfrs.choose(cap, tolerance=tol, candidates=cands, holdout=0.2, seed=5)
    meeting = [c for c in pick.candidates if c["error"] is not None and c["error"] <= tol]
    assert pick.met and pick.nbytes == min(c["nbytes"] for c in meeting)
    assert pick.error <= tol and np.array_equal(pick.lights_held, first.lights_held)
    text = pick.explain()
    assert "held out" in text and f"chosen: {pick.label}" in text and "fitted in" in text
    with pytest.raises(btfrs.InvalidArgumentError, match="holdout"):
        btfrs.choose(cap, tolerance=0.1, holdout=1.0)
    with pytest.raises(btfrs.InvalidArgumentError, match="holdout"):
        btfrs.choose(cap.select(lights=[0, 1]), tolerance=0.1, holdout=0.2)


def test_command_line_without_a_scene(capsys):
    from btfrs.cli import main

    rc = main(["choose", "--material", "bumps", "--size", "16", "--kinds", "ptm", "hsh", "raw",
               "--holdout", "0.2", "--tolerance", "0.5", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0 and "held out" in out and "chosen:" in out, out
