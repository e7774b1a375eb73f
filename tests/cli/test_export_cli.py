"""``napari-aldic export`` and ``params``, ``run --params-out`` and units in results."""

import json
import shutil
import sys

import numpy as np
import pytest
import scipy.io as sio
import tifffile
from PIL import Image

from napari_aldic.engine import load_result
from napari_aldic.engine.io import read_csv, read_vtu


@pytest.fixture
def folder(tmp_path, export_run_folder):
    """A private copy of the track() run folder."""
    dst = tmp_path / "run"
    shutil.copytree(export_run_folder, dst)
    return dst


@pytest.mark.slow  # ~5 s
def test_export_run_folder_to_many_formats(run_cli, folder, tmp_path, export_stack):
    rc, out, err = run_cli(["export", folder, "--to", "mat,csv", "vtu", "gif", "pdf",
                         "--pixel-size", 0.5, "--unit", "um", "--frame-interval", 0.1,
                         "--line", 10, 64, 118, 64, "--fps", 2])
    assert rc == 0, err
    assert "1 px = 0.5 um; frame interval 0.1 s" in out
    base = folder / "export"
    csv = read_csv(base.with_suffix(".csv"))
    assert csv["units"]["u"] == "um" and csv["units"]["vx"] == "um/s"
    assert sorted(set(csv["columns"]["frame"])) == list(range(len(export_stack)))
    d = sio.loadmat(base.with_suffix(".mat"))
    assert str(d["unit"][0]) == "um" and d["frames"].shape == (1, len(export_stack))
    assert base.with_suffix(".pvd").exists()
    v = read_vtu(folder / "export_frame00003.vtu")
    assert v["field_data"]["TimeValue"][0] == pytest.approx(0.3)
    with Image.open(folder / "export_u.gif") as im:
        assert im.n_frames == len(export_stack)
    assert (folder / "export.pdf").stat().st_size > 10_000


def test_export_single_file_name_and_fields(run_cli, folder, tmp_path):
    out_png = tmp_path / "fig.png"
    rc, out, err = run_cli(["export", folder / "frame_00002.npz", "--to", "png", "-o", out_png,
                         "--dpi", 60])
    assert rc == 0, err
    assert out_png.exists()
    rc, out, err = run_cli(["export", folder / "frame_00002.npz", "--to", "png", "--field", "u",
                         "exx", "-o", tmp_path / "maps", "--no-strain"])
    assert rc == 2  # exx needs strain: reported, u still written
    assert "needs strain" in err and (tmp_path / "maps_u.png").exists()


def test_export_errors_are_one_line(run_cli, folder, tmp_path):
    rc, _, err = run_cli(["export", folder, "--to", "csv", "-o", tmp_path / "missing" / "x"])
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("napari-aldic: error: csv: cannot write")
    assert "does not exist" in lines[0]
    assert not (tmp_path / "missing").exists()
    rc, _, err = run_cli(["export", tmp_path / "nothing.npz", "--to", "csv"])
    assert rc == 2 and "no such file" in err
    rc, _, err = run_cli(["export", folder, "--to", "xls"])
    assert rc == 2 and "unknown export format" in err
    rc, _, err = run_cli(["export", folder, "--to", "csv", "--pixel-size", 2])
    assert rc == 2 and "physical length unit" in err


def test_export_mp4_without_encoder_still_writes_gif(run_cli, folder, tmp_path, monkeypatch,
                                                     export_stack):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    rc, out, err = run_cli(["export", folder, "--to", "mp4", "gif", "-o", tmp_path / "anim",
                         "--no-strain"])
    assert rc == 2
    assert "imageio-ffmpeg" in err and "GIF" in err
    assert not (tmp_path / "anim_u.mp4").exists()
    with Image.open(tmp_path / "anim_u.gif") as im:
        assert im.n_frames == len(export_stack)


def test_export_mp4_without_encoder_says_it_once(run_cli, folder, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    rc, _, err = run_cli(["export", folder, "--to", "mp4", "--field", "u", "v", "-o",
                          tmp_path / "anim", "--no-strain"])
    assert rc == 2 and len(err.strip().splitlines()) == 1, err  # not once per field (issue 25)
    assert "imageio-ffmpeg" in err


def test_params_command_run_params_out_and_units_in_results(run_cli, tmp_path, export_stack):
    settings = tmp_path / "settings.json"
    rc, out, err = run_cli(["params", settings, "--subset", 21, "--step", 12,
                         "--pixel-size", 0.25, "--unit", "mm"])
    assert rc == 0, err
    doc = json.loads(settings.read_text())
    assert doc["params"]["subset"] == 21 and doc["units"]["unit"] == "mm"
    st = export_stack
    tif = tmp_path / "stack.tif"
    tifffile.imwrite(tif, st[:3], photometric="minisblack")
    used = tmp_path / "used.json"
    rc, out, err = run_cli(["run", tif, "--params", settings, "--step", 16, "-o",
                         tmp_path / "res", "--params-out", used])
    assert rc == 0, err
    doc = json.loads(used.read_text())
    assert doc["params"]["step"] == 16 and doc["params"]["subset"] == 21
    assert doc["units"] == {"pixel_size": 0.25, "unit": "mm", "frame_interval": None,
                            "time_unit": "s"}
    res = load_result(tmp_path / "res" / "frame_00002.npz")
    assert res.meta["units"]["unit"] == "mm"
    rc, out, err = run_cli(["export", tmp_path / "res", "--to", "csv", "--no-strain"])
    assert rc == 0, err
    csv = read_csv(tmp_path / "res" / "export.csv")
    assert csv["units"]["u"] == "mm"
    rows = csv["columns"]["frame"] == 2
    np.testing.assert_allclose(csv["columns"]["u"][rows], 0.25 * res.u, rtol=1e-9)


def test_params_writes_strain_and_tracking_and_checks_them(run_cli, tmp_path):
    first = tmp_path / "first.json"
    rc, _, err = run_cli(["params", first, "--step", 10, "--strain-window", 7,
                       "--strain-measure", "infinitesimal", "--reference", "incremental"])
    assert rc == 0, err
    doc = json.loads(first.read_text())
    assert doc["format"] == "napari-aldic-settings" and doc["params"]["step"] == 10
    assert doc["strain"] == {"window": 7, "method": "plane_fit", "measure": "infinitesimal"}
    assert doc["tracking"] == {"reference": "incremental"}
    # a file and options: every section of the file is kept, the options win
    second = tmp_path / "second.json"
    rc, _, err = run_cli(["params", second, "--params", first, "--strain-method", "fem"])
    assert rc == 0, err
    doc = json.loads(second.read_text())
    assert doc["params"]["step"] == 10 and doc["tracking"] == {"reference": "incremental"}
    assert doc["strain"] == {"window": 7, "method": "fem", "measure": "infinitesimal"}
    # invalid settings: one line naming the problem, nothing written
    for argv, expect in ((["--strain-window", 4], "strain window 4"),
                         (["--subset", 30], "subset=30")):
        rc, _, err = run_cli(["params", tmp_path / "bad.json", *argv])
        assert rc == 2 and expect in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "bad.json").exists()
    bad = tmp_path / "bad_section.json"
    bad.write_text(json.dumps({"params": {}, "tracking": {"reference": "sideways"}}))
    rc, _, err = run_cli(["params", tmp_path / "x.json", "--params", bad])
    assert rc == 2 and "sideways" in err and str(bad) in err
