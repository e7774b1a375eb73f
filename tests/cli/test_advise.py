"""``napari-aldic advise`` and ``napari-aldic noise-floor``."""

from __future__ import annotations

import json

import numpy as np
import tifffile

from napari_aldic.engine import synthetic as S


def _pair(tmp_path, noise=4.0):
    ref, dfm = S.speckle_pair((192, 192), S.Translation(0, 0), noise=noise, seed=7)
    tifffile.imwrite(tmp_path / "ref.tif", ref)
    tifffile.imwrite(tmp_path / "static.tif", dfm)
    return tmp_path / "ref.tif", tmp_path / "static.tif"


def test_advise_prints_the_table_and_the_recommendation(run_cli, tmp_path):
    ref, _ = _pair(tmp_path)
    roi = np.zeros((192, 192), bool)
    roi[20:170, 30:180] = True
    np.save(tmp_path / "roi.npy", roi)
    rc, out, err = run_cli(["advise", ref, "--roi", tmp_path / "roi.npy", "--target-noise",
                            0.02, "--subsets", 11, 21, 31, 41, "--json", tmp_path / "a.json"])
    assert rc == 0, err
    data = json.loads((tmp_path / "a.json").read_text(encoding="utf-8"))
    assert [r["subset"] for r in data["rows"]] == [11, 21, 31, 41]
    assert data["noise"] == np.float64(data["noise"]) and 3.5 < data["noise"] < 4.5
    rec = data["recommended"]
    first = next(r["subset"] for r in data["rows"] if r["fraction"] >= 0.9)
    assert rec == first
    assert f"recommended subset: {rec} px" in out
    for r in data["rows"]:
        assert f"{r['median_std_px']:.4f}" in out


def test_advise_says_when_no_subset_reaches_the_target(run_cli, tmp_path):
    ref, _ = _pair(tmp_path, noise=20.0)
    rc, out, err = run_cli(["advise", ref, "--target-noise", 1e-4, "--subsets", 11, 21])
    assert rc == 0, err
    assert "no tried subset reaches" in out


def test_advise_bad_input_gives_one_clear_line(run_cli, tmp_path):
    rc, out, err = run_cli(["advise", tmp_path / "missing.tif"])
    assert rc == 2 and "missing.tif" in err
    ref, _ = _pair(tmp_path)
    rc, out, err = run_cli(["advise", ref, "--target-noise", -1])
    assert rc == 2 and "target_noise" in err


def test_noise_floor_command_writes_the_floor(run_cli, tmp_path):
    ref, static = _pair(tmp_path)
    rc, out, err = run_cli(["noise-floor", ref, static, "--subset", 21, "--step", 10,
                            "-o", tmp_path / "nf.json"])
    assert rc == 0, err
    nf = json.loads((tmp_path / "nf.json").read_text(encoding="utf-8"))
    assert nf["subset"] == 21 and nf["n_valid"] > 100
    # 4 GL noise, 21 px subsets of this speckle: about 0.015 px
    assert 0.005 < nf["u_std_px"] < 0.03 and 0.005 < nf["v_std_px"] < 0.03
    assert abs(nf["drift_px"][0]) < 0.01
    assert f"u {nf['u_std_px']:.4f} px" in out
