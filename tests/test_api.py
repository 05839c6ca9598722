"""One Python API style: (height, width) sizes, keyword-only options, checked scalars, one error
hierarchy, bounds-checked accessors, progress on every long call, atomic writes."""

import inspect
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import btfrs
from btfrs import _native, _progress, synth
from btfrs.tools import demo
from btfrs.exceptions import (
    ArgumentTypeError,
    BtfrsError,
    DegenerateDataError,
    FormatError,
    InvalidArgumentError,
    OutOfRangeError,
)

ROOT = Path(__file__).resolve().parents[1]
D = btfrs.directions.ubo81()


@pytest.fixture(scope="module")
def tiny():
    return btfrs.materials.make("knit", size=8, seed=1)


@pytest.fixture(scope="module")
def an():
    tex = np.random.default_rng(0).random((24, 24, 3), dtype=np.float32)
    return synth.analyse(tex, textons=64, levels=1, m=4, neighbourhoods=(1,))


# --- the hierarchy ---------------------------------------------------------------------------


def test_the_new_classes_are_btfrs_errors_and_the_builtins_callers_catch():
    for cls, builtins in [(ArgumentTypeError, (TypeError, ValueError)), (OutOfRangeError, (IndexError, ValueError))]:
        assert issubclass(cls, InvalidArgumentError) and issubclass(cls, BtfrsError)
        for b in builtins:
            assert issubclass(cls, b)
    assert btfrs.ArgumentTypeError is ArgumentTypeError and btfrs.OutOfRangeError is OutOfRangeError


def test_no_plain_builtin_raise_is_left_in_the_modules_this_api_owns():
    # models.py is the model layer's (being rewritten); everything else raises btfrs errors only.
    for path in sorted((ROOT / "python" / "btfrs").rglob("*.py")):
        if path.name in ("models.py",):
            continue
        text = path.read_text()
        hits = re.findall(r"raise (ValueError|TypeError|IndexError|KeyError|OverflowError)\(", text)
        assert not hits, f"{path.name}: raise {hits}"


# --- (height, width) -------------------------------------------------------------------------


@pytest.mark.parametrize("backend", ["gpu", "cpu"])
def test_render_size_is_height_then_width(tiny, backend):
    ptm = btfrs.fit.ptm(tiny.select(views=[0, 1, 2, 3, 4, 5, 6]))
    cam = btfrs.Camera.look_at([0, -3, 2], [0, 0, 0], 40)
    img = btfrs.render(ptm, btfrs.Scene.sphere(), cam, btfrs.PointLight([2, -2, 3], 8.0), size=(24, 40),
                       backend=backend)
    assert img.shape == (24, 40, 3)
    # The sphere is centred: the lit columns are centred in a 40-wide image, the rows in 24.
    lit = img.sum(-1) > 0
    cols, rows = np.flatnonzero(lit.any(0)), np.flatnonzero(lit.any(1))
    assert abs((cols[0] + cols[-1]) / 2 - 19.5) <= 1.5 and abs((rows[0] + rows[-1]) / 2 - 11.5) <= 1.5
    assert btfrs.render(ptm, btfrs.Scene.sphere(), cam, btfrs.PointLight([2, -2, 3], 8.0), size=16,
                        backend=backend).shape == (16, 16, 3)


def test_synthesis_sizes_are_height_then_width(an):
    assert synth.kcoherence(an, size=(20, 30), k=2, neighbourhood=1, levels=1).shape == (20, 30, 2)
    assert synth.jump_map(an, size=(20, 30), neighbourhood=1).shape == (20, 30, 2)
    assert synth.tiled((24, 24), (20, 30)).shape == (20, 30, 2)
    assert synth.random_placement((24, 24), (20, 30)).shape == (20, 30, 2)


def test_cli_out_size_is_height_then_width(tmp_path):
    from btfrs.cli import main

    assert main(["synth", "--texture", str(_texture_png(tmp_path)), "--textons", "64", "--levels", "1",
                 "--neighbourhood", "1", "--method", "jump", "--out-size", "20", "36",
                 "--out", str(tmp_path / "o"), "--quiet"]) == 0
    assert np.load(tmp_path / "o" / "coords.npy").shape == (20, 36, 2)
    assert btfrs.io.load_image(tmp_path / "o" / "synthesized.png").shape == (20, 36, 3)


def _texture_png(tmp_path) -> Path:
    p = tmp_path / "tex.png"
    btfrs.io.save_image(p, np.random.default_rng(1).random((24, 24, 3), dtype=np.float32))
    return p


# --- keyword-only options ----------------------------------------------------------------------

# (function, the parameters that may stay positional: the data it works on)
PUBLIC = [
    (btfrs.fit.ptm, {"btf"}), (btfrs.fit.srf, {"btf"}), (btfrs.fit.lafortune, {"btf"}), (btfrs.fit.sh, {"btf"}),
    (btfrs.fit.lpca, {"btf"}), (btfrs.render, {"model", "scene", "camera", "lights"}),
    (btfrs.materials.make, {"name"}), (synth.analyse, {"sample"}), (synth.kcoherence, {"an"}),
    (synth.jump_map, {"an"}), (synth.quality, {"an", "coords"}), (synth.tiled, {"sample_shape", "size"}),
    (synth.random_placement, {"sample_shape", "size"}), (synth.apply, {"texture", "coords"}),
    (synth.Analysis.prepare, {"self", "neighbourhood", "levels"}),
    (btfrs.Btf.split, {"self"}), (btfrs.Btf.select, {"self"}), (btfrs.Btf.image, {"self", "view", "light"}),
    (btfrs.Btf.abrdf, {"self", "row", "col"}), (btfrs.Btf.__init__, {"self", "data", "views", "lights", "mask"}),
    (btfrs.io.save_image, {"path", "image"}), (btfrs.io.save_array, {"path", "array"}),
    (btfrs.io.save_text, {"path", "text"}), (btfrs.directions.from_theta_phi, {"theta", "phi"}),
    (btfrs.directions.to_theta_phi, {"d"}), (demo.run, {"out"}),
]


@pytest.mark.parametrize("fn, positional", PUBLIC, ids=lambda x: getattr(x, "__qualname__", ""))
def test_options_are_keyword_only(fn, positional):
    params = inspect.signature(fn).parameters.values()
    loose = [p.name for p in params if p.kind == p.POSITIONAL_OR_KEYWORD and p.name not in positional]
    assert not loose, f"{fn.__qualname__}: {loose} should be keyword-only"


def test_a_positional_option_is_refused(tiny):
    with pytest.raises(TypeError, match="positional"):
        btfrs.fit.ptm(tiny, "lrgb")
    with pytest.raises(TypeError, match="positional"):
        tiny.split(0.1)


# --- integers, floats and bools ----------------------------------------------------------------


def _calls(tiny, an):
    """(call, argument name, the exception it must raise)."""
    fit = btfrs.fit
    return [
        (lambda: fit.lafortune(tiny, lobes=2.9), "lobes", ArgumentTypeError),
        (lambda: fit.lafortune(tiny, lobes=True), "lobes", ArgumentTypeError),
        (lambda: fit.lafortune(tiny, lobes=0), "lobes", InvalidArgumentError),
        (lambda: fit.lafortune(tiny, max_iter=-3), "max_iter", InvalidArgumentError),
        (lambda: fit.lafortune(tiny, densify=1.5), "densify", ArgumentTypeError),
        (lambda: fit.lafortune(tiny, diffuse="yes"), "diffuse", ArgumentTypeError),
        (lambda: fit.lpca(tiny, clusters=-1), "clusters", InvalidArgumentError),
        (lambda: fit.lpca(tiny, clusters=2**70), "clusters", InvalidArgumentError),
        (lambda: fit.lpca(tiny, components=np.float64(2)), "components", ArgumentTypeError),
        (lambda: fit.lpca(tiny, kmeans_iterations=0), "kmeans_iterations", InvalidArgumentError),
        (lambda: fit.lpca(tiny, refine_iterations=-1), "refine_iterations", InvalidArgumentError),
        (lambda: fit.lpca(tiny, reduced_dims="64"), "reduced_dims", ArgumentTypeError),
        (lambda: fit.lpca(tiny, seed=-1), "seed", InvalidArgumentError),
        (lambda: fit.lpca(tiny, seed=2**64), "seed", InvalidArgumentError),
        (lambda: fit.sh(tiny, light_coeffs=16.0), "light_coeffs", ArgumentTypeError),
        (lambda: fit.sh(tiny, view_coeffs=-16), "view_coeffs", InvalidArgumentError),
        (lambda: fit.sh(tiny, chunk_texels=0), "chunk_texels", InvalidArgumentError),
        (lambda: fit.sh(tiny, cls=1), "cls", ArgumentTypeError),
        (lambda: fit.sh(tiny, quantize=None), "quantize", ArgumentTypeError),
        (lambda: fit.ptm(tiny, rcond=float("nan")), "rcond", InvalidArgumentError),
        (lambda: fit.ptm(tiny, rcond=-1.0), "rcond", InvalidArgumentError),
        (lambda: fit.ptm(tiny, on_degenerate="ignore"), "on_degenerate", InvalidArgumentError),
        (lambda: btfrs.materials.make("knit", size=16.0), "size", ArgumentTypeError),
        (lambda: btfrs.materials.make("knit", size=-1), "size", InvalidArgumentError),
        (lambda: btfrs.materials.make("knit", seed=True), "seed", ArgumentTypeError),
        (lambda: btfrs.materials.make("knit", relief=float("inf")), "relief", InvalidArgumentError),
        (lambda: btfrs.materials.make("knit", subsurface=1.0), "subsurface", InvalidArgumentError),
        (lambda: btfrs.materials.make(3), "name", ArgumentTypeError),
        (lambda: tiny.split(holdout=1.0), "holdout", InvalidArgumentError),
        (lambda: tiny.split(holdout="10%"), "holdout", ArgumentTypeError),
        (lambda: tiny.split(seed=0.5), "seed", ArgumentTypeError),
        (lambda: synth.analyse(np.zeros((8, 8, 3), np.float32), textons=-2), "textons", InvalidArgumentError),
        (lambda: synth.analyse(np.zeros((8, 8, 3), np.float32), levels=1.0), "levels", ArgumentTypeError),
        (lambda: synth.analyse(np.zeros((8, 8, 3), np.float32), m=0), "m", InvalidArgumentError),
        (lambda: synth.analyse(np.zeros((8, 8, 3), np.float32), iterations=-1), "iterations", InvalidArgumentError),
        (lambda: synth.analyse(np.zeros((8, 8, 3), np.float32), neighbourhoods=2), "neighbourhoods", ArgumentTypeError),
        (lambda: synth.analyse(np.zeros((8, 8, 3), np.float32), neighbourhoods=(0,)), "neighbourhoods",
         InvalidArgumentError),
        (lambda: synth.analyse(tiny, dims=0), "dims", InvalidArgumentError),
        (lambda: synth.analyse(tiny, images=2.5), "images", ArgumentTypeError),
        (lambda: synth.kcoherence(an, size=(20, -30)), r"size\[1\] \(width\)", InvalidArgumentError),
        (lambda: synth.kcoherence(an, size=(20.0, 30)), r"size\[0\] \(height\)", ArgumentTypeError),
        (lambda: synth.kcoherence(an, size=(1, 2, 3)), "size", ArgumentTypeError),
        (lambda: synth.kcoherence(an, k=-1), "k", InvalidArgumentError),
        (lambda: synth.kcoherence(an, neighbourhood=1.0), "neighbourhood", ArgumentTypeError),
        (lambda: synth.kcoherence(an, levels=0), "levels", InvalidArgumentError),
        (lambda: synth.kcoherence(an, toroidal=1), "toroidal", ArgumentTypeError),
        (lambda: synth.kcoherence(an, seed=-7), "seed", InvalidArgumentError),
        (lambda: synth.jump_map(an, jump=-0.1), "jump", InvalidArgumentError),
        (lambda: synth.jump_map(an, jump=True), "jump", ArgumentTypeError),
        (lambda: synth.jump_map(an, neighbourhood=-1), "neighbourhood", InvalidArgumentError),
        (lambda: synth.quality(an, synth.tiled((24, 24), 16), samples=0), "samples", InvalidArgumentError),
        (lambda: synth.quality(an, synth.tiled((24, 24), 16), neighbourhood=0.5), "neighbourhood", ArgumentTypeError),
        (lambda: synth.tiled((24.0, 24), 16), r"sample_shape\[0\]", ArgumentTypeError),
        (lambda: synth.random_placement((24, 24), 16, seed=-1), "seed", InvalidArgumentError),
        (lambda: an.texton_map(1), "level", OutOfRangeError),
        (lambda: an.dots(-1), "level", OutOfRangeError),
        (lambda: an.similar(neighbourhood=0), "neighbourhood", InvalidArgumentError),
        (lambda: an.prepare(1, 0), "levels", InvalidArgumentError),
        (lambda: btfrs.io.save_image("x.png", np.zeros((2, 2, 3)), exposure=float("nan")), "exposure",
         InvalidArgumentError),
        (lambda: btfrs.directions.from_theta_phi(0.1, 0.2, degrees="yes"), "degrees", ArgumentTypeError),
    ]


def test_every_scalar_argument_is_checked_by_name(tiny, an):
    for i, (call, name, exc) in enumerate(_calls(tiny, an)):
        with pytest.raises(exc, match=f"^{name}: expected") as info:
            call()
        # Never PyO3's OverflowError or an unnamed TypeError, and always a btfrs error.
        assert isinstance(info.value, BtfrsError) and not isinstance(info.value, OverflowError), i


def test_checked_integers_accept_numpy_integers_and_name_the_range(tiny):
    m = btfrs.fit.lafortune(tiny.select(views=list(range(20))), lobes=np.int64(1), max_iter=np.int32(5))
    assert m.height == 8
    with pytest.raises(ArgumentTypeError, match=r"^lobes: expected an integer from 1 to 7, got 2\.9$"):
        btfrs.fit.lafortune(tiny, lobes=2.9)
    with pytest.raises(InvalidArgumentError, match=r"^clusters: expected an integer >= 1, got -1$"):
        btfrs.fit.lpca(tiny, clusters=-1)
    # Above the texels: the fit's own check, which knows the count.
    with pytest.raises(InvalidArgumentError, match=r"^clusters: expected 1 to 65536, got 9223372036854775808$"):
        btfrs.fit.lpca(tiny, clusters=2**63)
    with pytest.raises(ArgumentTypeError, match=r"^clusters: expected an integer >= 1, got 1\.8"):
        btfrs.fit.lpca(tiny, clusters=2**64)
    with pytest.raises(InvalidArgumentError, match=r"^size: expected an integer in \[8, 1024\], got 4$"):
        btfrs.materials.make("knit", size=4)


# --- every converted raise ---------------------------------------------------------------------


def test_each_converted_error_is_a_btfrs_error(tiny, an):
    ptm = btfrs.fit.ptm(tiny.select(views=[0, 1, 2]))
    cam = btfrs.Camera.look_at([0, -3, 2], [0, 0, 0], 40)
    sc = btfrs.Scene.plane()
    light = btfrs.PointLight([0, 0, 2], 1.0)
    data = np.zeros((1, 1, 2, 2, 3), np.float32)
    cases = [
        # btf.py
        (lambda: btfrs.Btf(data, np.array([["a", "b", "c"]] * 2), D[:2]), ArgumentTypeError, "views"),
        (lambda: btfrs.Btf(data, D[:2, :2], D[:2]), InvalidArgumentError, "views"),
        (lambda: btfrs.Btf(data.astype(np.int32), D[:2], D[:2]), ArgumentTypeError, "data"),
        (lambda: btfrs.Btf(data[0], D[:2], D[:2]), InvalidArgumentError, "data"),
        (lambda: btfrs.Btf(data, D[:2], D[:2], np.ones((2, 2), np.uint8)), ArgumentTypeError, "mask"),
        (lambda: tiny.image(81, 0), OutOfRangeError, "view"),
        (lambda: tiny.image(0, -1), OutOfRangeError, "light"),
        (lambda: tiny.image(0.0, 0), ArgumentTypeError, "view"),
        (lambda: tiny.select(views=[]), InvalidArgumentError, "views/lights"),
        (lambda: tiny.select(views=[0, 81]), OutOfRangeError, "views"),
        (lambda: tiny.select(lights=[-1]), OutOfRangeError, "lights"),
        (lambda: tiny.select(views=[0.5]), ArgumentTypeError, "views"),
        (lambda: tiny.select(views=np.ones(3, bool)), InvalidArgumentError, "views"),
        (lambda: btfrs.ExpandedBtf("btf", np.zeros((1, 1, 2), np.uint16)), ArgumentTypeError, "sample"),
        (lambda: tiny.expand(np.zeros((1, 1, 2), np.int32)), ArgumentTypeError, "coords"),
        (lambda: tiny.expand(np.zeros((1, 2), np.uint16)), InvalidArgumentError, "coords"),
        # rendering.py
        (lambda: btfrs.render(ptm, "plane", cam, light), ArgumentTypeError, "scene"),
        (lambda: btfrs.render(ptm, sc, "cam", light), ArgumentTypeError, "camera"),
        (lambda: btfrs.render(ptm, sc, cam, ["light"]), ArgumentTypeError, "lights"),
        (lambda: btfrs.render(ptm, sc, cam, 3.0), ArgumentTypeError, "lights"),
        (lambda: btfrs.render(ptm, sc, cam, light, size=8, coords=np.zeros((2, 2, 2), np.int64)), ArgumentTypeError,
         "coords"),
        (lambda: btfrs.render("ptm", sc, cam, light), ArgumentTypeError, "model"),
        (lambda: btfrs.render(ptm, sc, cam, light, uv_scale=0), InvalidArgumentError, "uv_scale"),
        (lambda: btfrs.render(ptm, sc, cam, light, uv_scale=(1, 2, 3)), InvalidArgumentError, "uv_scale"),
        (lambda: btfrs.render(ptm, sc, cam, light, size="big"), ArgumentTypeError, "size"),
        # fit.py, hemimap.py, directions.py, io.py, _progress.py
        (lambda: btfrs.fit.ptm(tiny.data), ArgumentTypeError, "btf"),
        (lambda: btfrs.hemimap.square_to_disk(np.array(["a", "b"])), ArgumentTypeError, "st"),
        (lambda: btfrs.directions.to_theta_phi(np.zeros((3, 2))), InvalidArgumentError, "d"),
        (lambda: btfrs.io.save_image("a.tif", np.zeros((2, 2, 3))), InvalidArgumentError, "path"),
        (lambda: btfrs.fit.ptm(tiny, progress="yes"), ArgumentTypeError, "progress"),
        # synth.py
        (lambda: synth.analyse(np.zeros(5)), InvalidArgumentError, "sample"),
        (lambda: synth.analyse(np.zeros((4, 4, 3), np.complex64)), ArgumentTypeError, "sample"),
        (lambda: synth.kcoherence("an"), ArgumentTypeError, "an"),
        (lambda: synth.quality(an, np.zeros((4, 4, 2), np.int64)), ArgumentTypeError, "coords"),
        (lambda: synth.quality(an, np.zeros((4, 4), np.uint16)), InvalidArgumentError, "coords"),
        (lambda: synth.apply(np.zeros(4), np.zeros((2, 2, 2), np.uint16)), InvalidArgumentError, "texture"),
        # the native module (arrays.rs, io.rs, hemimap.rs)
        (lambda: _native.validate_btf(data.astype(np.float64), D[:2], D[:2]), ArgumentTypeError, "data"),
        (lambda: _native.save_container("x.btfrs", "btf", "{}", [("a", np.zeros(2, np.int64))]), ArgumentTypeError,
         "a"),
        (lambda: _native.square_to_disk(np.zeros((2, 2), np.int32)), ArgumentTypeError, "st"),
    ]
    for i, (call, exc, name) in enumerate(cases):
        with pytest.raises(exc, match=f"^{re.escape(name)}: ") as info:
            call()
        assert isinstance(info.value, BtfrsError), (i, info.value)
    assert not os.path.exists("x.btfrs")


def test_fit_errors_stay_distinct_from_argument_errors():
    few = btfrs.materials.make("knit", size=8, seed=1).select(views=[0], lights=[0, 1, 2])
    with pytest.raises(DegenerateDataError):
        btfrs.fit.ptm(few, on_degenerate="raise")
    with pytest.raises(FormatError):
        btfrs.load(ROOT / "README.md")


# --- bounds-checked accessors ------------------------------------------------------------------


def test_abrdf_is_bounds_checked_and_never_wraps(tiny):
    np.testing.assert_array_equal(tiny.abrdf(7, 0), tiny.data[7, 0])
    for row, col, name in [(-1, 0, "row"), (8, 0, "row"), (0, -1, "col"), (0, 8, "col")]:
        with pytest.raises(OutOfRangeError, match=rf"^{name}: expected an index in \[0, 8\), got {row if name == 'row' else col}$"):
            tiny.abrdf(row, col)
    with pytest.raises(IndexError):  # an OutOfRangeError is still an IndexError
        tiny.abrdf(-1, -1)
    with pytest.raises(ArgumentTypeError, match="^row: "):
        tiny.abrdf(1.0, 0)
    big = tiny.expand(np.zeros((3, 5, 2), np.uint16))
    np.testing.assert_array_equal(big.abrdf(2, 4), tiny.data[0, 0])
    with pytest.raises(OutOfRangeError, match=r"^col: expected an index in \[0, 5\), got -1"):
        big.abrdf(0, -1)
    with pytest.raises(OutOfRangeError, match="^view: "):
        big.image(-1, 0)


def test_select_keeps_the_axis_for_one_index_and_accepts_masks(tiny):
    one = tiny.select(views=3)
    assert one.n_views == 1 and np.array_equal(one.views[0], tiny.views[3])
    mask = np.zeros(81, bool)
    mask[[2, 5]] = True
    assert np.array_equal(tiny.select(lights=mask).lights, tiny.lights[[2, 5]])
    assert tiny.select(views=np.int64(0)).n_views == 1


# --- typing_extensions -------------------------------------------------------------------------


def test_typing_extensions_is_not_imported_undeclared():
    declared = "typing_extensions" in (ROOT / "pyproject.toml").read_text()
    for path in sorted((ROOT / "python" / "btfrs").rglob("*.py*")):
        if "typing_extensions" in path.read_text():
            assert declared, f"{path.name} imports typing_extensions, which pyproject.toml does not declare"


# --- progress ------------------------------------------------------------------------------------


def test_render_and_jump_map_report_progress(tiny, an):
    ptm = btfrs.fit.ptm(tiny.select(views=[0, 1, 2, 3]))
    cam = btfrs.Camera.look_at([0, -3, 2], [0, 0, 0], 40)
    for backend, want in (("gpu", [(0, 2), (1, 2), (2, 2)]), ("cpu", [(0, 1), (1, 1)])):
        seen = []
        btfrs.render(ptm, btfrs.Scene.plane(), cam, btfrs.PointLight([0, 0, 2], 1.0), size=(8, 12), backend=backend,
                     progress=lambda d, t: seen.append((d, t)))
        assert seen == want, backend
    seen = []
    cmap = synth.jump_map(an, size=(40, 30), neighbourhood=1, seed=3, progress=lambda d, t: seen.append((d, t)))
    # Rows are the units; the last report is the whole map.
    assert seen and seen[-1] == (40, 40) and all(t == 40 and 0 <= d <= 40 for d, t in seen)
    np.testing.assert_array_equal(cmap, synth.jump_map(an, size=(40, 30), neighbourhood=1, seed=3))


def test_jump_map_progress_can_cancel(an):
    # The map takes about half a second here; the first progress poll comes after 0.1 s.
    seen = []

    def stop(done, total):
        seen.append((done, total))
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        synth.jump_map(an, size=(4000, 4000), neighbourhood=1, progress=stop)
    assert len(seen) == 1 and seen[0][0] < seen[0][1] == 4000  # stopped mid-way, not at the end


def test_progress_off_a_terminal_is_one_line_per_phase(tiny, an, capsys):
    # pytest's capture makes stderr a non-terminal, as a log file or CI is.
    assert not sys.stderr.isatty()
    btfrs.fit.ptm(tiny, progress=True)
    synth.kcoherence(an, size=(32, 32), k=2, neighbourhood=1, levels=1, progress=True)
    btfrs.render(btfrs.fit.ptm(tiny.select(views=[0, 1, 2])), btfrs.Scene.plane(),
                 btfrs.Camera.look_at([0, -3, 2], [0, 0, 0], 40), btfrs.PointLight([0, 0, 2], 1.0), size=(8, 12),
                 progress=True)
    err = capsys.readouterr().err
    assert "\r" not in err
    lines = err.splitlines()
    assert re.fullmatch(r"ptm fit: (\d+)/\1 in \d+\.\d\d s", lines[0]), lines
    assert any(re.fullmatch(r"k-coherence: (\d+)/\1 in \d+\.\d\d s", x) for x in lines), lines
    assert lines[-1].startswith("render 8x12 (upload, draw + read-back): 2/2 in ")
    assert len(lines) == len(set(lines))  # each phase once, though the runner reports the end twice


def test_progress_on_a_terminal_is_a_bar(tiny, capsys, monkeypatch):
    monkeypatch.setattr(_progress, "_stderr_is_terminal", lambda: True)
    monkeypatch.setitem(sys.modules, "tqdm", None)  # the built-in bar, whether tqdm is installed or not
    btfrs.fit.ptm(tiny, progress=True)
    err = capsys.readouterr().err
    assert err.startswith("\rptm fit") and "100%" in err and err.endswith("\n")


def test_the_cli_logs_one_line_per_phase(tmp_path):
    import subprocess

    r = subprocess.run([sys.executable, "-m", "btfrs.cli", "synth", "--texture", str(_texture_png(tmp_path)),
                        "--textons", "64", "--levels", "1", "--neighbourhood", "1", "--out-size", "32", "32",
                        "--out", str(tmp_path / "o")], capture_output=True, text=True,
                       env=dict(os.environ, XDG_RUNTIME_DIR="/tmp"))
    assert r.returncode == 0, r.stderr
    assert "\r" not in r.stderr and re.search(r"^k-coherence: (\d+)/\1 in ", r.stderr, re.M), r.stderr


# --- atomic writes -------------------------------------------------------------------------------


def _leftovers(folder: Path) -> list:
    return [p.name for p in folder.iterdir() if p.name.endswith((".tmp", ".btfrs-tmp"))]


@pytest.mark.skipif(not Path("/proc/self").exists(), reason="which processes run is read from /proc")
@pytest.mark.parametrize("next_writer", ["rust", "python"])
def test_a_killed_writer_leaves_a_temporary_file_that_the_next_write_removes(tmp_path, next_writer):
    # SIGKILL a process while it writes a large BTF straight into a file (btfrs-io's atomic
    # writer): its temporary file stays, since nothing can run in a killed process. The next
    # write into the folder, by Rust or by Python's atomic_write, sees that its writer is gone and
    # removes it; the half-written target never appears.
    import signal

    code = ("import btfrs, sys\n"
            "def tick(d, t):\n"
            "    if d: print('writing', flush=True)\n"
            "btfrs.materials.make('knit', size=256, out=sys.argv[1], progress=tick)\n")
    target = tmp_path / "big.btfrs"
    p = subprocess.Popen([sys.executable, "-c", code, str(target)], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout is not None and p.stdout.readline().strip() == "writing"
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=60)
    finally:
        p.kill()
        if p.stdout is not None:
            p.stdout.close()
    left = _leftovers(tmp_path)
    assert len(left) == 1 and left[0].endswith(f".{p.pid}.0.btfrs-tmp") and not target.exists(), left
    if next_writer == "rust":
        btfrs.fit.ptm(btfrs.materials.make("knit", size=8, seed=1)).save(tmp_path / "small.btfrs")
    else:
        btfrs.io.save_text(tmp_path / "note.txt", "next\n")
    assert _leftovers(tmp_path) == [] and not target.exists()


def test_atomic_write_leaves_the_old_file_when_interrupted(tmp_path):
    target = tmp_path / "coords.npy"
    btfrs.io.save_array(target, np.arange(6))
    for exc in (OSError("disk full"), KeyboardInterrupt()):
        with pytest.raises(type(exc)):
            with btfrs.io.atomic_write(target) as f:
                f.write(b"\x93NUMPY half a header")
                raise exc
        np.testing.assert_array_equal(np.load(target), np.arange(6))
        assert _leftovers(tmp_path) == []
    with pytest.raises(OSError):
        with btfrs.io.atomic_write(tmp_path / "new.txt", "w") as f:
            f.write("half")
            raise OSError("disk full")
    assert not (tmp_path / "new.txt").exists() and _leftovers(tmp_path) == []
    btfrs.io.save_text(tmp_path / "new.txt", "done\n")
    assert (tmp_path / "new.txt").read_text() == "done\n"
    # The file gets the permissions a plain open() would give (the umask's), not mkstemp's 0600.
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    assert (tmp_path / "new.txt").stat().st_mode == plain.stat().st_mode


def test_cli_synth_never_leaves_a_half_written_map(tmp_path, monkeypatch):
    from btfrs.cli import main

    out = tmp_path / "o"
    out.mkdir()
    (out / "coords.npy").write_bytes(b"old")
    real_save = np.save

    def failing_save(f, a, *args, **kwargs):
        real_save(f, a[: len(a) // 2], *args, **kwargs)  # half of it reaches the file...
        raise OSError("No space left on device")  # ...then the disk fills up

    monkeypatch.setattr(np, "save", failing_save)
    rc = main(["synth", "--texture", str(_texture_png(tmp_path)), "--textons", "64", "--levels", "1",
               "--neighbourhood", "1", "--method", "jump", "--out-size", "16", "16", "--out", str(out), "--quiet"])
    assert rc == 2
    assert (out / "coords.npy").read_bytes() == b"old" and _leftovers(out) == []


def test_the_demo_writes_only_through_atomic_writers():
    # demo.py and cli.py write files only through btfrs.io (atomic) or the native writers (atomic
    # in Rust): no np.save, open(..., "w"), write_text or write_bytes of their own.
    for name in ("tools/demo.py", "cli.py"):
        text = (ROOT / "python" / "btfrs" / name).read_text()
        for pattern in (r"np\.save\(", r"\bopen\(", r"\.write_text\(", r"\.write_bytes\(", r"\.tofile\("):
            assert not re.search(pattern, text), (name, pattern)
