"""``btfrs info | fit | export | render`` end to end on an RTI folder and a UBO-style archive made
here, and their errors (exit code 2, one line naming the problem)."""

from __future__ import annotations

import numpy as np
import pytest
from test_captures import H, RTI_LIGHTS, W, shade, srgb8_to_linear, to_srgb8, write_lp, write_ubo

import btfrs
from btfrs import io
from btfrs.cli import main


def test_rti_folder_info_fit_export_render(tmp_path, capsys):
    write_lp(tmp_path / "cap")
    assert main(["info", str(tmp_path / "cap"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert f"{H} x {W} texels, 1 view x 10 lights" in out
    assert "yes ptm" in out and "yes hsh" in out and "yes lpca" in out and "theta 10.0 to 70.0 deg" in out
    model = tmp_path / "lion_ptm.btfrs"
    assert main(["fit", str(tmp_path / "cap" / "dirs.lp"), "--model", "ptm", "-o", str(tmp_path / "h.btfrs"),
                 "--quiet", "--holdout", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "reconstruction error" in out and "held-out error" in out
    assert main(["fit", str(tmp_path / "cap" / "dirs.lp"), "--model", "ptm", "-o", str(model), "--quiet"]) == 0
    m = btfrs.load(model)
    assert isinstance(m, btfrs.Ptm) and (m.height, m.width) == (H, W)
    # the fitted PTM predicts a measured image of the Lambertian relief (a biquadratic fits it well)
    got = m.evaluate([0, 0, 1], RTI_LIGHTS[1])
    want = srgb8_to_linear(to_srgb8(shade(RTI_LIGHTS[1])))
    assert np.abs(got - want).mean() < 0.1 * want.mean()
    assert main(["export", str(model), "--ptm", str(tmp_path / "lion.ptm"), "--exr", str(tmp_path / "lion.exr")]) == 0
    back = io.load(tmp_path / "lion.ptm")
    np.testing.assert_allclose(back.evaluate([0, 0, 1], RTI_LIGHTS[1]), got, atol=0.02)
    assert (tmp_path / "lion.exr").stat().st_size > 0
    png = tmp_path / "lion.png"
    assert main(["render", str(model), "--scene", "plane", "--light", "0.3", "0.2", "0.93", "--image-size", "64", "64",
                 "-o", str(png), "--backend", "cpu"]) == 0
    img = io.load_image(png)
    assert img.shape == (64, 64, 3) and img.mean() > 0.05


def test_ubo_archive_fit_and_render_gpu_matches_cpu(tmp_path, capsys):
    write_ubo(tmp_path / "imgs", zip_path=tmp_path / "cloth.zip")
    assert main(["info", str(tmp_path / "cloth.zip"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "3 views x 6 lights" in out and "no  hsh" in out and "only 6" in out
    model = tmp_path / "cloth_lpca.btfrs"
    assert main(["fit", str(tmp_path / "cloth.zip"), "--model", "lpca", "--set", "clusters=4", "--set",
                 "components=3", "-o", str(model), "--quiet"]) == 0
    for backend in ("cpu", "gpu"):
        assert main(["render", str(model), "--scene", "sphere", "--image-size", "48", "48", "-o",
                     str(tmp_path / f"{backend}.exr"), "--backend", backend]) == 0
    cpu, gpu = io.load_image(tmp_path / "cpu.exr"), io.load_image(tmp_path / "gpu.exr")
    assert cpu.max() > 0
    assert np.abs(cpu - gpu).max() < 0.02 * cpu.max()
    # the raw capture renders too (the measured data interpolated)
    assert main(["render", str(tmp_path / "cloth.zip"), "-o", str(tmp_path / "raw.png"), "--image-size", "32", "32",
                 "--backend", "cpu"]) == 0


def test_export_stack_round_trip_and_errors(tmp_path, capsys):
    b = btfrs.materials.make("bumps", size=8, seed=1).select(views=[0, 5], lights=[0, 1, 2])
    b.save(tmp_path / "b.btfrs")
    assert main(["export", str(tmp_path / "b.btfrs"), "--stack", str(tmp_path / "st")]) == 0
    np.testing.assert_array_equal(io.load(tmp_path / "st", directions=tmp_path / "st" / "directions.csv").data, b.data)
    capsys.readouterr()
    assert main(["fit", str(tmp_path / "nowhere.lp"), "--model", "ptm", "-o", str(tmp_path / "x.btfrs")]) == 2
    assert "nowhere.lp" in capsys.readouterr().err
    assert main(["fit", str(tmp_path / "b.btfrs"), "--model", "ptm", "--set", "bogus=1", "-o",
                 str(tmp_path / "x.btfrs"), "--quiet"]) == 2
    assert "bogus" in capsys.readouterr().err
    assert not (tmp_path / "x.btfrs").exists()
    assert main(["export", str(tmp_path / "b.btfrs"), "--ptm", str(tmp_path / "x.ptm")]) == 2
    assert "not a model" in capsys.readouterr().err
    assert main(["info", str(tmp_path / "b.btfrs"), "--crop", "0", "0", "99", "99"]) == 2
    assert "crop" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["fit", "x.lp"], ["render", "x"]])
def test_missing_arguments_are_usage_errors(argv):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2


def test_a_command_without_input_names_what_it_takes(capsys):
    assert main(["info"]) == 2
    assert "path: expected a capture or btfrs file, or --material NAME" in capsys.readouterr().err


@pytest.mark.parametrize("argv, flag", [
    (["fit", "--material", "knit", "--size", "8", "--model", "ptm", "-o", "{tmp}/missing/m.btfrs"], "-o"),
    (["fit", "--material", "knit", "--size", "8", "--model", "ptm", "-o", "{tmp}"], "-o"),
    (["fit", "--material", "knit", "--size", "8", "--model", "ptm", "-o", "{tmp}/m.png"], "-o"),
    (["fit", "{tmp}/in.btfrs", "--model", "ptm", "-o", "{tmp}/in.btfrs"], "-o"),
    (["render", "--material", "knit", "--size", "8", "-o", "{tmp}/x.jpg"], "-o"),
    (["export", "{tmp}/in.btfrs", "--ptm", "{tmp}/x.rti"], "--ptm"),
    (["evaluate", "--material", "knit", "--size", "8", "--out", "{tmp}/in.btfrs"], "--out"),
    (["fit", "--material", "knit", "--size", "8", "--model", "lafortune", "--set", "lobes=NaN", "-o", "{tmp}/m.btfrs"],
     "--set lobes"),
    (["fit", "--material", "knit", "--size", "8", "--model", "ptm", "--set", "progress=1", "-o", "{tmp}/m.btfrs"],
     "--set progress"),
])
def test_output_paths_and_options_are_refused_before_any_work(argv, flag, tmp_path, capsys, monkeypatch):
    # Nothing is loaded, generated or fitted before the arguments are known to be usable: the
    # material generator and the fit would fail the test if called.
    btfrs.materials.make("knit", size=8, seed=1).save(tmp_path / "in.btfrs")
    before = sorted(p.name for p in tmp_path.iterdir())

    def no_work(*a, **k):
        raise AssertionError("work started before the arguments were checked")

    monkeypatch.setattr(btfrs.materials, "make", no_work)
    monkeypatch.setattr(btfrs.fit, "fit", no_work)
    assert main([a.replace("{tmp}", str(tmp_path)) for a in argv]) == 2
    err = capsys.readouterr().err
    assert f"btfrs: error: {flag}" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written, the input intact
