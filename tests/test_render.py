"""The renderer from Python: GPU (lavapipe in CI) against the CPU reference, and bad input."""

import numpy as np
import pytest

import btfrs
from btfrs.exceptions import InvalidArgumentError


def psnr(a, b):
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    peak = float(max(a.max(), b.max()))
    return np.inf if mse == 0 else 10 * np.log10(peak * peak / mse)


@pytest.fixture(scope="module")
def weave():
    return btfrs.materials.make("weave", size=16, seed=2)


@pytest.fixture(scope="module")
def models(weave):
    return {"raw": weave, "ptm-rgb": btfrs.fit.ptm(weave), "ptm-lrgb": btfrs.fit.ptm(weave, kind="lrgb")}


CAM = dict(eye=[0, -3, 2], target=[0, 0, 0], fov_deg=40)
LIGHTS = [btfrs.PointLight(position=[2, -2, 3], intensity=8.0), btfrs.DirectionalLight(direction=[-1, -0.5, 1], intensity=[0.4, 0.3, 0.2])]


def scenes():
    t = np.linspace(0, 1, 9, dtype=np.float32)
    u, v = np.meshgrid(t, t)
    verts = np.stack([2 * u - 1, 2 * v - 1, 0.2 * np.sin(3 * u) * np.cos(2 * v)], -1).reshape(-1, 3)
    uvs = np.stack([u, v], -1).reshape(-1, 2)
    idx = np.arange(81, dtype=np.uint32).reshape(9, 9)
    faces = np.concatenate([np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:]], -1).reshape(-1, 3),
                            np.stack([idx[:-1, :-1], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 3)])
    return {"plane": btfrs.Scene.plane(), "sphere": btfrs.Scene.sphere(), "cylinder": btfrs.Scene.cylinder(),
            "mesh": btfrs.Scene.mesh(verts, uvs, faces)}


@pytest.mark.parametrize("scene", ["plane", "sphere", "cylinder", "mesh"])
@pytest.mark.parametrize("model", ["raw", "ptm-rgb", "ptm-lrgb"])
def test_gpu_matches_the_cpu_reference(models, scene, model):
    sc = scenes()[scene]
    cam = btfrs.Camera.look_at(**CAM)
    m = models[model]
    gpu = btfrs.render(m, sc, cam, LIGHTS, size=(64, 80), uv_scale=3)
    cpu = btfrs.render(m, sc, cam, LIGHTS, size=(64, 80), uv_scale=3, backend="cpu")
    assert gpu.shape == (64, 80, 3) and gpu.dtype == np.float32
    assert (cpu.sum(-1) > 0).mean() > 0.1, "nothing drawn"
    assert psnr(gpu, cpu) >= 40.0


def test_coordinate_maps(weave, models):
    cam = btfrs.Camera.look_at(**CAM)
    sc = btfrs.Scene.sphere()
    # The identity map gives the same image as no map.
    yy, xx = np.mgrid[0:16, 0:16]
    ident = np.stack([xx, yy], -1).astype(np.uint16)
    a = btfrs.render(models["ptm-rgb"], sc, cam, LIGHTS, size=64, uv_scale=2)
    b = btfrs.render(models["ptm-rgb"], sc, cam, LIGHTS, size=64, uv_scale=2, coords=ident)
    np.testing.assert_array_equal(a, b)
    # A map larger than the sample renders on GPU as on CPU.
    big = np.stack([(xx.repeat(3, 0).repeat(3, 1) * 5 + 1) % 16, (yy.repeat(3, 0).repeat(3, 1) * 3) % 16], -1).astype(np.uint16)
    g = btfrs.render(weave, sc, cam, LIGHTS, size=64, coords=big)
    c = btfrs.render(weave, sc, cam, LIGHTS, size=64, coords=big, backend="cpu")
    assert psnr(g, c) >= 40.0 and not np.allclose(g, btfrs.render(weave, sc, cam, LIGHTS, size=64))


def test_bad_input_names_the_argument(models):
    m = models["ptm-rgb"]
    cam = btfrs.Camera.look_at(**CAM)
    sc = btfrs.Scene.plane()
    with pytest.raises(InvalidArgumentError, match="size"):
        btfrs.render(m, sc, cam, LIGHTS, size=(0, 10))
    with pytest.raises(InvalidArgumentError, match=r"size\[0\] \(height\): expected an integer in \[1, 16384\], got 100000"):
        btfrs.render(m, sc, cam, LIGHTS, size=(100000, 10))
    with pytest.raises(InvalidArgumentError, match="coords: entry"):
        btfrs.render(m, sc, cam, LIGHTS, size=8, coords=np.full((2, 2, 2), 99, np.uint16))
    with pytest.raises(TypeError, match="coords"):
        btfrs.render(m, sc, cam, LIGHTS, size=8, coords=np.zeros((2, 2, 2), np.int64))
    with pytest.raises(TypeError, match="scene"):
        btfrs.render(m, "sphere", cam, LIGHTS)
    with pytest.raises(InvalidArgumentError, match="lights"):
        btfrs.render(m, sc, cam, [], size=8)
    with pytest.raises(InvalidArgumentError, match="intensity"):
        btfrs.render(m, sc, cam, [btfrs.PointLight([0, 0, 1], intensity=-1)], size=8)
    with pytest.raises(InvalidArgumentError, match="backend"):
        btfrs.render(m, sc, cam, LIGHTS, size=8, backend="vulkan")
    with pytest.raises(ValueError, match="camera|eye"):
        btfrs.Camera.look_at(eye=[0, 0, 0], target=[0, 0, 0])
    train, _ = models["raw"].split(holdout=0.1, seed=0)
    with pytest.raises(ValueError, match="every \\(view, light\\) pair"):
        btfrs.render(train, sc, cam, LIGHTS, size=8)


def test_bad_meshes():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], np.float32)
    uv = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], np.float32)
    with pytest.raises(ValueError, match="faces"):
        btfrs.Scene.mesh(v, uv, np.array([[0, 1, 7]], np.uint32))
    with pytest.raises(ValueError, match="faces"):  # zero area: three collinear points
        btfrs.Scene.mesh(v, uv, np.array([[0, 1, 3]], np.uint32))
    bad = v.copy()
    bad[1, 0] = np.nan
    with pytest.raises(ValueError, match="positions"):
        btfrs.Scene.mesh(bad, uv, np.array([[0, 1, 2]], np.uint32))
    with pytest.raises(ValueError, match="uvs"):
        btfrs.Scene.mesh(v, np.zeros((4, 2), np.float32), np.array([[0, 1, 2]], np.uint32))
    with pytest.raises(ValueError, match="uvs: expected shape"):
        btfrs.Scene.mesh(v, uv[:, :1].copy(), np.array([[0, 1, 2]], np.uint32))
    assert btfrs.Scene.mesh(v, uv, np.array([[0, 1, 2]], np.uint32)).triangles == 1


def test_plane_from_above_shows_the_sample(weave):
    # A far, narrow camera straight above a plane under an overhead light sees every texel from
    # (almost) the normal: the image is the BTF's (view 0, light 0) image, times the irradiance.
    cam = btfrs.Camera.look_at(eye=[0, 0, 60], target=[0, 0, 0], fov_deg=2 * np.degrees(np.arctan(1 / 60)))
    light = btfrs.DirectionalLight(direction=[0, 0, 1], intensity=1.0)
    img = btfrs.render(weave, btfrs.Scene.plane(2.0), cam, [light], size=(32, 32))
    want = weave.image(0, 0).repeat(2, 0).repeat(2, 1)
    assert np.abs(img - want).mean() / want.mean() < 0.05


def test_renders_save_as_png_and_exact_exr(tmp_path, models):
    img = btfrs.render(models["ptm-rgb"], btfrs.Scene.sphere(), btfrs.Camera.look_at(**CAM), LIGHTS, size=(40, 48))
    btfrs.io.save_image(tmp_path / "a.exr", img)
    np.testing.assert_array_equal(btfrs.io.load_image(tmp_path / "a.exr"), img)
    btfrs.io.save_image(tmp_path / "a.png", img)
    assert btfrs.io.load_image(tmp_path / "a.png").shape == (40, 48, 3)
    with pytest.raises(ValueError, match="path: expected a .png or .exr"):
        btfrs.io.save_image(tmp_path / "a.tif", img)


def test_a_missing_adapter_is_a_clear_device_error():
    import os
    import subprocess
    import sys

    code = (
        "import btfrs\n"
        "try:\n"
        "    btfrs.gpu_info()\n"
        "except btfrs.exceptions.DeviceError as e:\n"
        "    print('DeviceError:', e)\n"
    )
    env = dict(os.environ, BTFRS_ADAPTER="no-such-adapter", XDG_RUNTIME_DIR="/tmp")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env).stdout
    assert out.startswith("DeviceError:") and "matches none of the adapters found" in out
