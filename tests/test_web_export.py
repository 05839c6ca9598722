"""The viewer's export and server, without a browser: what `btfrs export --web`, `save_web` and
`btfrs view` write and serve, and their refusals (the browser side is tests/test_viewer.py)."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request

import numpy as np
import pytest

import btfrs
import btfrs.web
from btfrs.cli import main
from btfrs.exceptions import InvalidArgumentError


@pytest.fixture(scope="module")
def hsh(tmp_path_factory):
    d = tmp_path_factory.mktemp("web")
    m = btfrs.fit.hsh(btfrs.materials.make("bumps", size=8, seed=1), order=2)
    m.save(d / "h.btfrs")
    return m, d / "h.btfrs"


def test_the_bundle_is_what_the_native_renderer_uploads(hsh, tmp_path):
    model, _ = hsh
    page = btfrs.web.save_web(model, tmp_path / "site")
    assert page == str(tmp_path / "site" / "index.html")
    man = json.loads((tmp_path / "site" / "model" / "manifest.json").read_text())
    assert man["model"]["kind"] == "hsh" and man["model"]["nbytes"] == model.nbytes
    assert man["model"]["views"] == len(model.views)
    # The shader is common.wgsl + the generated Params + the model's own file.
    shader = (tmp_path / "site" / "model" / "shader.wgsl").read_text()
    root = os.path.join(os.path.dirname(__file__), "..", "shaders_wgsl")
    with open(os.path.join(root, "hsh.wgsl")) as f:
        assert f.read() in shader
    assert "struct Params" in shader and "fn vs_main" in shader
    # The Globals layout comes from the Rust struct: increasing offsets, ending before its size.
    g = man["layout"]["globals"]
    offsets = [f["offset"] for f in g["fields"]]
    assert offsets == sorted(offsets) and offsets[0] == 0 and offsets[-1] < g["size"]
    # Every file the manifest names exists; the mesh buffers match their counts.
    files = man["files"]
    for f in files.values():
        assert (tmp_path / "site" / "model" / f).is_file()
    for scene in man["scenes"].values():
        n = (tmp_path / "site" / "model" / scene["indices"]).stat().st_size // 4
        assert n == scene["index_count"] and n % 3 == 0
        nv = (tmp_path / "site" / "model" / scene["vertices"]).stat().st_size // man["layout"]["vertex"]["stride"]
        idx = np.fromfile(tmp_path / "site" / "model" / scene["indices"], "<u4")
        assert idx.max() < nv
    # The viewer's modules are beside it, the generated list of kinds among them.
    kinds = (tmp_path / "site" / "kinds.js").read_text()
    assert all(json.dumps(k) in kinds for k in btfrs.model_kinds())


def test_the_model_method_writes_the_same_viewer(hsh, tmp_path):
    model, _ = hsh
    page = model.save_web(tmp_path / "m", uv_scale=3)
    assert page == str(tmp_path / "m" / "index.html")
    btfrs.web.save_web(model, tmp_path / "w", uv_scale=3)
    for name in ("manifest.json", "store.bin", "shader.wgsl"):
        assert (tmp_path / "m" / "model" / name).read_bytes() == (tmp_path / "w" / "model" / name).read_bytes()
    assert json.loads((tmp_path / "m" / "model" / "manifest.json").read_text())["uv_scale"] == [3.0, 3.0]


def test_an_existing_target_is_refused_unless_forced(hsh, tmp_path):
    model, path = hsh
    out = tmp_path / "site"
    btfrs.web.save_web(model, out)
    with pytest.raises(InvalidArgumentError, match="exists"):
        btfrs.web.save_web(model, out)
    btfrs.web.save_web(model, out, force=True)
    assert main(["export", str(path), "--web", str(out)]) == 2
    assert main(["export", str(path), "--web", str(out), "--force"]) == 0
    single = tmp_path / "one.html"
    assert main(["export", str(path), "--web", str(single), "--single-file"]) == 0
    text = single.read_text()
    assert 'id="btfrs-data"' in text and "import " not in text.split('<script type="module">')[1]
    assert main(["export", str(path), "--web", str(tmp_path / "x.txt"), "--single-file"]) == 2
    with pytest.raises(InvalidArgumentError, match="fitted btfrs model"):
        btfrs.web.save_web(btfrs.materials.make("bumps", size=8, seed=1), tmp_path / "b")


def test_btfrs_view_serves_the_viewer_and_takes_another_port_when_one_is_busy(hsh):
    _, path = hsh
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    port = busy.getsockname()[1]
    p = subprocess.Popen([sys.executable, "-m", "btfrs.cli", "view", str(path), "--no-browser", "--port", str(port)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        lines = [p.stdout.readline(), p.stdout.readline()]
        assert f"port {port} is not available" in lines[0], lines
        url = lines[1].split(" at ")[1].split()[0]
        with urllib.request.urlopen(url + "model/manifest.json", timeout=30) as r:
            assert json.loads(r.read())["model"]["kind"] == "hsh"
        with urllib.request.urlopen(url, timeout=30) as r:
            assert b"viewer.js" in r.read()
    finally:
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=60)
        busy.close()
    assert p.returncode == 130, err


def test_btfrs_view_of_something_that_is_not_a_model_fails_with_a_message(tmp_path):
    (tmp_path / "x.foo").write_text("hello")
    r = subprocess.run([sys.executable, "-m", "btfrs.cli", "view", str(tmp_path / "x.foo"), "--no-browser"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "unknown file type" in r.stderr


def test_a_coordinate_map_or_a_tile_set_goes_into_the_manifest_with_its_globals(hsh, tmp_path, capsys):
    model, path = hsh
    # A coordinate map: its words are the map's (x | y << 16), row-major; map_size is (W, H).
    rng = np.random.default_rng(2)
    coords = rng.integers(0, 8, (5, 7, 2)).astype(np.uint16)
    np.save(tmp_path / "c.npy", coords)
    assert main(["export", str(path), "--web", str(tmp_path / "c"), "--coords", str(tmp_path / "c.npy"),
                 "--uv-scale", "2"]) == 0
    man = json.loads((tmp_path / "c" / "model" / "manifest.json").read_text())
    assert man["map"]["kind"] == "coords" and man["map"]["map_size"] == [7, 5] and man["uv_scale"] == [2.0, 2.0]
    words = np.fromfile(tmp_path / "c" / "model" / man["map"]["file"], dtype="<u4")
    want = coords[..., 0].astype(np.uint32) | coords[..., 1].astype(np.uint32) << 16
    assert np.array_equal(words, want.ravel())
    # A tile set of the model's texels: the layout's cells then the atlas; tiles = (side,
    # columns, rows, atlas width in texels), tile_atlas = (where the atlas starts, ...).
    ts = btfrs.tiles.wang(model, tile=4, edge_height=2, colors=2, seed=1, progress=False)
    ts.save(tmp_path / "t.btfrs")
    assert main(["export", str(tmp_path / "t.btfrs"), "--web", str(tmp_path / "t"), "--layout", "3", "5"]) == 0
    man = json.loads((tmp_path / "t" / "model" / "manifest.json").read_text())
    assert man["map"]["kind"] == "tiles" and man["map"]["tiles"] == [4, 5, 3, 16] and man["map"]["tile_atlas"][0] == 15
    words = np.fromfile(tmp_path / "t" / "model" / man["map"]["file"], dtype="<u4")
    pos = ts.atlas_positions()[ts.tiling(3, 5, seed=0)]
    assert np.array_equal(words[:15], (pos[..., 0] << 16 | pos[..., 1]).ravel())
    assert np.array_equal(words[15:], ts.atlas.ravel()) and man["model"]["width"] == len(ts.btfels)
    # Refusals: a map pointing outside the sample, a tile set with a coordinate map.
    bad = coords.copy()
    bad[4, 6] = (8, 0)
    with pytest.raises(InvalidArgumentError, match=r"coords: entry \(8, 0\) at map row 4, column 6"):
        btfrs.web.save_web(model, tmp_path / "bad", coords=bad)
    assert not (tmp_path / "bad").exists()
    assert main(["export", str(tmp_path / "t.btfrs"), "--web", str(tmp_path / "t2"), "--coords",
                 str(tmp_path / "c.npy")]) == 2
    assert "--coords: a tile set draws its own tiling" in capsys.readouterr().err
