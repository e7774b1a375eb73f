"""``napari-aldic sem-calibrate``, ``sem-drift`` and ``run --distortion --drift
--scan-lines`` (issue 27) on small synthetic SEM images."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile

from napari_aldic.engine import load_result
from napari_aldic.engine.synthetic import (
    Affine,
    SEMScan,
    Translation,
    make_pattern,
    random_line_shifts,
    sem_image,
)

N = 192
SCAN = SEMScan((N, N), k1=0.6e-3, p1=2.8e-3, dwell=2e-6, flyback=1e-4,
               drift_x=(0.5,), drift_y=(-0.3,))
FIELD = Affine.strain_rotation(exx=0.005, eyy=-0.0015, center=((N - 1) / 2,) * 2, t=(6, -5))


@pytest.fixture(scope="module")
def sem_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sem")
    pat = make_pattern((N, N), margin=50, seed=4)
    moves = [(0, 0), (18, 0), (0, 18), (-18, 0), (0, -18)]
    cal = []
    for k, m in enumerate(moves):
        cal.append(folder / f"T{k}.tif")
        tifffile.imwrite(cal[-1], sem_image(pat, SCAN, Translation(*m), noise=1.5, seed=k,
                                            use_drift=False))
    F = SCAN.frame_time
    series = []
    for k in range(3):
        series.append(folder / f"S{k}.tif")
        tifffile.imwrite(series[-1], sem_image(pat, SCAN, None, start_time=k * F, noise=1.5,
                                               seed=50 + k, use_distortion=False))
    lines = random_line_shifts(N, seed=3)
    ref, dfm = folder / "ref.tif", folder / "def.tif"
    tifffile.imwrite(ref, sem_image(pat, SCAN, None, noise=1.5, seed=80, use_drift=False))
    tifffile.imwrite(dfm, sem_image(pat, SCAN, FIELD, line_shifts=lines, noise=1.5, seed=81,
                                    use_drift=False))
    return folder, cal, series, ref, dfm


def test_sem_calibrate_and_run(run_cli, sem_files):
    folder, cal, _, ref, dfm = sem_files
    out = folder / "distortion.json"
    rc, text, err = run_cli(["sem-calibrate", *cal, "-o", out, "--degree", 3])
    assert rc == 0, err
    d = json.loads(out.read_text())
    assert d["format"] == "napari-aldic-sem-distortion" and d["version"] == 1
    assert len(d["images"]) == 5 and d["image_shape"] == [N, N]
    assert abs(d["images"][1]["translation_px"][0] - 18) < 0.1
    res_path = folder / "res.npz"
    rc, text, err = run_cli(["run", ref, dfm, "--distortion", out, "--scan-lines",
                             "-o", res_path])
    assert rc == 0, err
    res = load_result(res_path)
    assert res.meta["sem"]["distortion"]["degree"] == 3
    assert len(res.meta["sem"]["scan_lines"]["deformed"]["rows"]) > 0
    assert (folder / "res_scanlines.png").stat().st_size > 1000
    ux, uy = FIELD.displacement(res.x, res.y)
    ok = res.valid
    assert np.sqrt(np.mean((res.u - ux)[ok] ** 2 + (res.v - uy)[ok] ** 2)) < 0.03
    # tiled pairs get the same correction
    rc, _, err = run_cli(["run", ref, dfm, "--distortion", out, "--tile-size", 128,
                          "-o", folder / "tiled.npz"])
    assert rc == 0, err
    tiled = load_result(folder / "tiled.npz")
    assert "distortion" in tiled.meta["sem"]


def test_sem_drift_and_stack(run_cli, sem_files):
    folder, _, series, _, _ = sem_files
    out = folder / "drift.json"
    rc, text, err = run_cli(["sem-drift", *series, "-o", out, "--dwell", SCAN.dwell,
                             "--line-time", SCAN.line_time, "--degree", 1])
    assert rc == 0, err
    d = json.loads(out.read_text())
    assert d["format"] == "napari-aldic-sem-drift"
    assert d["coef_x"][0] / d["t_scale_s"] == pytest.approx(0.5, abs=0.02)
    stack = folder / "stack.tif"
    tifffile.imwrite(stack, np.stack([tifffile.imread(p) for p in series]),
                     photometric="minisblack")
    rc, text, err = run_cli(["run", stack, "--drift", out, "-o", folder / "runs"])
    assert rc == 0, err
    for k in (1, 2):
        res = load_result(folder / "runs" / f"frame_{k:05d}.npz")
        assert np.abs(res.u[res.valid]).max() < 0.03  # the unmoved area, drift removed


def test_sem_cli_errors(run_cli, sem_files, tmp_path):
    folder, cal, series, ref, dfm = sem_files
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    rc, _, err = run_cli(["run", ref, dfm, "--distortion", bad, "-o", tmp_path / "r.npz"])
    assert rc == 2 and "not a napari-aldic distortion calibration" in err
    rc, _, err = run_cli(["sem-drift", *series, "-o", tmp_path / "d.json"])
    assert rc == 2 and "--dwell" in err
    rc, _, err = run_cli(["sem-calibrate", *cal, "-o", tmp_path / "x.json", "--degree", 9])
    assert rc == 2 and "degree 9" in err
