"""The svbrdf model written for other renderers: the Mitsuba 3 scene rendered by Mitsuba itself
against btfrs's render of the model, the glTF asset read by pygltflib (an independent glTF
reader) and Pillow against the glTF 2.0 specification, both read back by btfrs, and the refusals."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

import btfrs
from btfrs.exceptions import FormatError, InvalidArgumentError

from conftest import in_ci
from test_svbrdf import truth_model

IN_CI = in_ci()


def _need(module: str):
    try:
        return __import__(module)
    except ImportError:
        if IN_CI:
            raise
        pytest.skip(f"{module} is not installed")


@pytest.fixture(scope="module")
def bumps() -> btfrs.Svbrdf:
    return btfrs.fit.svbrdf(btfrs.materials.make("bumps", size=32, seed=0))


def srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


# --- Mitsuba -----------------------------------------------------------------------------------

def test_mitsuba_renders_the_exported_scene_as_btfrs_renders_the_model(bumps):
    _need("mitsuba")
    from btfrs.tools import groundtruth as gt

    res = gt.check_export(bumps, size=96, supersample=4, spp=512, seed=0)
    rows = {(r["light"], r["case"]): r for r in res["rows"]}
    for light in ("theta 40, phi 60", "theta 65, phi 200"):
        ok, bad = rows[(light, "exported")], rows[(light, "rows mirrored")]
        # Measured 1.0011 / 40.2 dB and 1.0013 / 45.0 dB; what remains is Monte Carlo noise
        # and the texel edges inside pixels, which 4 x 4 pixel centres resolve only in part.
        assert abs(ok["brightness"] - 1.0) < 0.02, ok
        assert ok["psnr"] >= 35.0, ok
        # The control: the texture upside down (9.7 and 16.3 dB) must fail the same bar.
        assert bad["psnr"] < 25.0, bad
        assert ok["pixels"] > 4000


def test_the_mitsuba_scene_reads_back_exactly_and_states_the_blend(tmp_path):
    m = truth_model(5, 6)
    info = m.export(tmp_path / "scene", format="mitsuba")
    assert sorted(info["files"]) == sorted(["diffuse.exr", "specular.exr", "roughness.exr", "normal.exr", "scene.xml"])
    # The maps hold twice the colours (a blend of weight 0.5) and (n + 1) / 2, as float32 EXR.
    np.testing.assert_array_equal(btfrs.io.load_image(tmp_path / "scene" / "diffuse.exr"), 2 * m.diffuse)
    np.testing.assert_array_equal(btfrs.io.load_image(tmp_path / "scene" / "specular.exr"), 2 * m.specular)
    np.testing.assert_allclose(btfrs.io.load_image(tmp_path / "scene" / "normal.exr"), 0.5 * m.normals + 0.5, atol=1e-7)
    xml = (tmp_path / "scene" / "scene.xml").read_text()
    for needle in ('<bsdf type="normalmap">', '<bsdf type="blendbsdf">', '<float name="weight" value="0.5"/>',
                   '<string name="material" value="none"/>', '<string name="distribution" value="ggx"/>'):
        assert needle in xml
    back = btfrs.load(tmp_path / "scene")
    assert back.kind == "svbrdf"
    for name, a in m.arrays.items():
        np.testing.assert_allclose(back.arrays[name], a, rtol=0, atol=2e-7, err_msg=name)


# --- glTF --------------------------------------------------------------------------------------

def _accessor(g, path, i: int) -> np.ndarray:
    """Accessor ``i``'s data from the buffer file, by the spec's rules (float32 or uint16)."""
    acc = g.accessors[i]
    view = g.bufferViews[acc.bufferView]
    data = (path / g.buffers[view.buffer].uri).read_bytes()
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[acc.type]
    dtype = {5126: "<f4", 5123: "<u2"}[acc.componentType]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    a = np.frombuffer(data, dtype, count=acc.count * width, offset=start)
    return a.reshape(acc.count, width) if width > 1 else a


def test_the_gltf_asset_is_where_the_specification_puts_it(bumps, tmp_path):
    pygltflib = _need("pygltflib")
    from PIL import Image

    out = tmp_path / "asset"
    info = bumps.export(out / "material.gltf")
    assert info["clipped"] == {"diffuse": int((bumps.diffuse > 1).sum()), "specular": int((bumps.specular > 1).sum())}
    g = pygltflib.GLTF2().load(str(out / "material.gltf"))
    assert g.asset.version == "2.0"
    assert set(g.extensionsUsed) == {"KHR_materials_specular", "KHR_materials_ior"}
    prim = g.meshes[g.nodes[g.scenes[g.scene].nodes[0]].mesh].primitives[0]
    mat = g.materials[prim.material]
    pbr = mat.pbrMetallicRoughness
    assert pbr.metallicFactor == 0.0 and pbr.roughnessFactor == 1.0 and pbr.baseColorFactor == [1.0] * 4
    ext = mat.extensions
    assert ext["KHR_materials_ior"] == {"ior": 0.0}  # F0 = the specular colour (spec-gloss form)
    assert ext["KHR_materials_specular"]["specularFactor"] == 1.0
    assert ext["KHR_materials_specular"]["specularColorFactor"] == [1.0, 1.0, 1.0]

    def image(tex_index: int) -> np.ndarray:
        tex = g.textures[tex_index]
        s = g.samplers[tex.sampler]
        assert (s.magFilter, s.minFilter, s.wrapS, s.wrapT) == (9729, 9987, 10497, 10497)
        img = g.images[tex.source]
        assert img.mimeType == "image/png" and "/" not in img.uri
        with Image.open(out / img.uri) as im:  # Pillow reads 16-bit RGB PNGs as 8 bits
            assert im.size == (bumps.width, bumps.height)
            return np.asarray(im.convert("RGB"), np.float64) / 255.0

    tol = 1.0 / 255 + 1e-6
    # Base colour and specular colour: sRGB-encoded (the spec's rule for colour textures).
    np.testing.assert_allclose(image(pbr.baseColorTexture.index), srgb(bumps.diffuse), atol=tol)
    np.testing.assert_allclose(image(ext["KHR_materials_specular"]["specularColorTexture"]["index"]),
                               srgb(bumps.specular), atol=tol)
    # Roughness in green, metallic in blue, linear; glTF's roughness squared is GGX's alpha.
    mr = image(pbr.metallicRoughnessTexture.index)
    np.testing.assert_allclose(mr[..., 1], np.sqrt(bumps.roughness), atol=tol)
    assert mr[..., 2].max() == 0.0
    # Normals: (n + 1) / 2, tangent space.
    assert mat.normalTexture.scale == 1.0
    np.testing.assert_allclose(image(mat.normalTexture.index), 0.5 * bumps.normals + 0.5, atol=tol)
    # The square: positions, normals, tangents and texture coordinates as the spec lays them out.
    at = prim.attributes
    pos, nrm, tan, uv = (_accessor(g, out, i) for i in (at.POSITION, at.NORMAL, at.TANGENT, at.TEXCOORD_0))
    idx = _accessor(g, out, prim.indices)
    assert g.buffers[0].byteLength == (out / g.buffers[0].uri).stat().st_size
    np.testing.assert_array_equal(g.accessors[at.POSITION].min, pos.min(0))
    np.testing.assert_array_equal(g.accessors[at.POSITION].max, pos.max(0))
    tri = pos[idx.reshape(-1, 3)]
    face = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert (face @ nrm[0] > 0).all()  # counter-clockwise from the side the normal faces
    # The tangent runs along +u; the bitangent (normal x tangent, times w) up the texture's
    # rows, i.e. towards decreasing v (glTF's v runs down the image): where the normal map's +Y
    # (btfrs's y, up the rows) must point.
    duv = np.linalg.lstsq(np.c_[uv, np.ones(4)], pos, rcond=None)[0]  # pos = u dP/du + v dP/dv + c
    bitangent = np.cross(nrm[0], tan[0, :3]) * tan[0, 3]
    np.testing.assert_allclose(tan[0, :3] / np.linalg.norm(tan[0, :3]), duv[0] / np.linalg.norm(duv[0]), atol=1e-6)
    np.testing.assert_allclose(bitangent, -duv[1] / np.linalg.norm(duv[1]), atol=1e-6)


def test_the_gltf_asset_reads_back_within_16_bits(tmp_path):
    m = truth_model(5, 6)
    m.export(tmp_path / "asset", format="gltf")
    back = btfrs.load(tmp_path / "asset")
    assert back.kind == "svbrdf"
    step = 1 / 65535
    np.testing.assert_allclose(back.diffuse, m.diffuse, atol=20 * step)  # sRGB steps are wider near 1
    np.testing.assert_allclose(back.specular, m.specular, atol=20 * step)
    np.testing.assert_allclose(np.sqrt(back.roughness), np.sqrt(m.roughness), atol=step)
    np.testing.assert_allclose(back.normals, m.normals, atol=3 * step)


def test_colours_a_gltf_cannot_hold_are_clipped_and_counted(tmp_path):
    a = truth_model(3, 4).arrays
    a["diffuse"][0, 0] = [1.5, 0.2, 2.0]
    m = btfrs.Model.from_arrays(a, kind="svbrdf")
    info = m.export(tmp_path / "asset", format="gltf")
    assert info["clipped"] == {"diffuse": 2, "specular": 0}
    np.testing.assert_allclose(btfrs.load(tmp_path / "asset").diffuse[0, 0], [1.0, 0.2, 1.0], atol=1e-3)


# --- refusals ----------------------------------------------------------------------------------

def test_an_existing_folder_is_refused_unless_forced(tmp_path):
    m = truth_model()
    for fmt in ("gltf", "mitsuba"):
        out = tmp_path / fmt
        m.export(out, format=fmt)
        with pytest.raises(InvalidArgumentError, match=r"exists and is not empty; pass force=True"):
            m.export(out, format=fmt)
        m.export(out, format=fmt, force=True)
        (tmp_path / f"{fmt}.file").write_text("x")
        with pytest.raises(InvalidArgumentError, match="is a file; expected a folder"):
            m.export(tmp_path / f"{fmt}.file", format=fmt)


def test_other_models_and_bad_maps_are_refused(tmp_path):
    btf = btfrs.materials.make("knit", size=8, seed=0)
    ptm = btfrs.fit.ptm(btf)
    with pytest.raises(InvalidArgumentError, match=r"cannot be written as 'gltf'.*'ptm'"):
        ptm.export(tmp_path / "a", format="gltf")
    a = truth_model().arrays
    a["roughness"][1, 1] = np.nan
    with pytest.raises(InvalidArgumentError, match="roughness"):
        btfrs.Model.from_arrays(a, kind="svbrdf")
    a = truth_model().arrays
    a["normal"][0, 0] = 0.0
    with pytest.raises(InvalidArgumentError, match="normal"):
        btfrs.Model.from_arrays(a, kind="svbrdf")


def test_a_gltf_from_a_stranger_is_confined_and_checked(tmp_path):
    truth_model().export(tmp_path / "a", format="gltf")
    doc = json.loads((tmp_path / "a" / "material.gltf").read_text())

    def load_with(edit, match):
        d = json.loads(json.dumps(doc))
        edit(d)
        (tmp_path / "a" / "material.gltf").write_text(json.dumps(d))
        with pytest.raises(FormatError, match=match):
            btfrs.load(tmp_path / "a")

    def uri(u):
        return lambda d: d["images"][0].update(uri=u)

    load_with(uri("../secret.png"), r"images\[0\]\.uri.*a file name in the asset's folder")
    load_with(uri("/etc/passwd"), r"images\[0\]\.uri")
    load_with(uri("data:image/png;base64,AAAA"), r"images\[0\]\.uri")
    load_with(uri("missing.png"), "does not exist beside the asset")
    load_with(lambda d: d["materials"][0]["pbrMetallicRoughness"].update(metallicFactor=1.0), "only non-metals")
    load_with(lambda d: d["materials"][0].pop("normalTexture"), "normalTexture: missing")
    load_with(lambda d: d["asset"].update(version="1.0"), "asset.version")
    load_with(lambda d: d["materials"][0]["pbrMetallicRoughness"].update(baseColorFactor=[1, 1]), "baseColorFactor")
    (tmp_path / "a" / "material.gltf").write_text(json.dumps(doc))
    (tmp_path / "a" / "normal.png").write_bytes((tmp_path / "a" / "normal.png").read_bytes()[:60])
    with pytest.raises(FormatError, match="normal.png"):
        btfrs.load(tmp_path / "a")


def test_a_mitsuba_scene_of_another_form_is_refused_by_line(tmp_path):
    truth_model().export(tmp_path / "s", format="mitsuba")
    p = tmp_path / "s" / "scene.xml"
    xml = p.read_text()
    p.write_text(xml.replace('<bsdf type="blendbsdf">', '<bsdf type="plastic">'))
    with pytest.raises(FormatError, match=r"line \d+: expected a blendbsdf BSDF"):
        btfrs.load(tmp_path / "s")
    p.write_text(xml.replace('value="normal.exr"', 'value="../normal.exr"'))
    with pytest.raises(FormatError, match="expected an .exr file name in the scene's folder"):
        btfrs.load(tmp_path / "s")
    p.write_text(xml.replace('value="none"', 'value="Au"'))
    with pytest.raises(FormatError, match="material"):
        btfrs.load(tmp_path / "s")


def test_the_cli_writes_both_and_refuses_to_overwrite(tmp_path, capsys):
    from btfrs.cli import main

    m = truth_model()
    m.save(tmp_path / "m.btfrs")
    args = ["export", str(tmp_path / "m.btfrs"), "--gltf", str(tmp_path / "g"), "--mitsuba", str(tmp_path / "s")]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert f"wrote {tmp_path / 'g'}" in out and f"wrote {tmp_path / 's'}" in out
    assert (tmp_path / "g" / "material.gltf").exists() and (tmp_path / "s" / "scene.xml").exists()
    assert main(args) == 2
    assert "--gltf: " in (err := capsys.readouterr().err) and "exists and is not empty; pass --force" in err
    assert main(args + ["--force"]) == 0
