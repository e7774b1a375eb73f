"""``napari-aldic probe``: the fixed contract (options, columns, one row per frame)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

LINE_COLUMNS = ("strain", "true_strain", "elongation", "cod_opening", "cod_sliding",
                "cod_magnitude")




def _rows(path):
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        return reader.fieldnames, list(reader)


def _truth(field, x0, y0, x1, y1):
    u, v = field.displacement(np.array([x0, x1], float), np.array([y0, y1], float))
    L = np.hypot(x1 - x0, y1 - y0)
    ell = np.hypot(x1 - x0 + u[1] - u[0], y1 - y0 + v[1] - v[0])
    e = np.array([x1 - x0, y1 - y0]) / L
    return (ell - L) / L, ell - L, (u[1] - u[0]) * e[0] + (v[1] - v[0]) * e[1]


def test_probe_contract_columns_and_values(run_cli, export_run_folder, export_field, tmp_path):
    lines = [(20, 64, 108, 64), (64, 20, 64, 108)]
    out = tmp_path / "probes.csv"
    argv = ["probe", export_run_folder]
    for ln in lines:
        argv += ["--line", *ln]
    rc, stdout, err = run_cli([*argv, "--point", 50, 70, "--area", 30, 30, 90, 90, "-o", out])
    assert rc == 0, err
    names, rows = _rows(out)
    assert names[0] == "frame"
    for i in (1, 2):
        for q in LINE_COLUMNS:
            assert f"line{i}_{q}" in names
    assert "point1_u" in names and "area1_exx_mean" in names
    assert [int(r["frame"]) for r in rows] == [0, 1, 2, 3]  # one row per frame
    assert all(float(rows[0][f"line1_{q}"]) == 0 for q in LINE_COLUMNS)  # the reference
    for k in (1, 2, 3):
        for i, ln in enumerate(lines, 1):
            strain, elong, opening = _truth(export_field(k), *ln)
            r = rows[k]
            assert abs(float(r[f"line{i}_strain"]) - strain) < 2e-4
            assert abs(float(r[f"line{i}_true_strain"]) - np.log1p(strain)) < 2e-4
            assert abs(float(r[f"line{i}_elongation"]) - elong) < 0.02
            assert abs(float(r[f"line{i}_cod_opening"]) - opening) < 0.02
            assert r[f"line{i}_status"] == "ok"
    assert "lengths in px" in stdout
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["units"]["line1_elongation"] == "px"
    assert "load_N" not in names


def test_probe_load_by_time_and_stress(run_cli, export_run_folder, tmp_path):
    load = tmp_path / "machine.csv"
    load.write_text("Tensile test, specimen 7\nTime;Standard force\n(s);(kN)\n"
                    "0,0;0,0\n0,5;1,0\n1,0;2,0\n1,5;3,0\n", encoding="utf-8")
    out = tmp_path / "p.csv"
    rc, stdout, err = run_cli(["probe", export_run_folder, "--line", 20, 64, 108, 64,
                            "--load", load, "--area-mm2", 4, "--sync", "time", "--fps", 4,
                            "--offset", 0.5, "-o", out])
    assert rc == 0, err
    names, rows = _rows(out)
    assert "load_N" in names and "stress_MPa" in names
    # frame k at k/4 + 0.5 s: 0.5, 0.75, 1.0, 1.25 s -> 1, 1.5, 2, 2.5 kN
    np.testing.assert_allclose([float(r["load_N"]) for r in rows], [1000, 1500, 2000, 2500])
    np.testing.assert_allclose([float(r["stress_MPa"]) for r in rows], [250, 375, 500, 625])
    # an offset past the record leaves those frames empty (never extrapolated)
    rc, stdout, err = run_cli(["probe", export_run_folder, "--line", 20, 64, 108, 64,
                            "--load", load, "--area-mm2", 4, "--sync", "time", "--fps", 2,
                            "--offset", 0.75, "-o", out])
    assert rc == 0, err
    _, rows = _rows(out)
    assert [r["load_N"] for r in rows] == ["1500", "2500", "", ""]
    assert rows[3]["load_status"] == "missing" and "outside the load record" in \
        rows[3]["load_reason"]
    assert "load: missing at frame(s) 2, 3" in stdout


def test_probe_units_result_file_and_extras(run_cli, export_run_folder, tmp_path):
    out = tmp_path / "one.csv"
    rc, stdout, err = run_cli(["probe", export_run_folder / "frame_00002.npz", "--line", 20, 64,
                            108, 64, "--pixel-size", 0.5, "--unit", "um", "-o", out,
                            "--plot", "png", "--kymograph", "u"])
    assert rc == 0, err
    names, rows = _rows(out)
    assert [int(r["frame"]) for r in rows] == [0, 2]
    strain = float(rows[1]["line1_strain"])
    assert float(rows[1]["line1_elongation"]) == pytest.approx(0.5 * 88 * strain, rel=1e-6)
    assert json.loads(out.with_suffix(".json").read_text())["units"]["line1_elongation"] == "um"
    assert out.with_suffix(".png").stat().st_size > 5000
    kymo = tmp_path / "one_line1_u.csv"
    assert "distance [um]" in kymo.read_text()


@pytest.mark.parametrize("extra, message", [
    ([], "give at least one probe"),
    (["--line", 1, 1, 1, 1], "two gauge points are the same"),
    (["--line", 0, 0, 9, 9, "--load", "LOAD"], "--load needs --area-mm2"),
    (["--line", 0, 0, 9, 9, "--area-mm2", 3], "go with --load"),
])
def test_probe_errors_are_one_clear_line(run_cli, export_run_folder, tmp_path, extra, message):
    extra = [tmp_path / "l.csv" if a == "LOAD" else a for a in extra]
    rc, out, err = run_cli(["probe", export_run_folder, *extra, "-o", tmp_path / "x.csv"])
    assert rc == 2 and message in err and "Traceback" not in err
    assert err.count("\n") == 1


def test_probe_bad_inputs_name_the_file(run_cli, export_run_folder, tmp_path):
    rc, _, err = run_cli(["probe", tmp_path / "nothing", "--line", 0, 0, 9, 9, "-o",
                       tmp_path / "x.csv"])
    assert rc == 2 and "nothing" in err
    bad = tmp_path / "bad.csv"
    bad.write_text("Time,Force\n(s),(furlongs)\n0,1\n1,2\n")
    rc, _, err = run_cli(["probe", export_run_folder, "--line", 0, 0, 9, 9, "--load", bad,
                       "--area-mm2", 2, "--fps", 1, "-o", tmp_path / "x.csv"])
    assert rc == 2 and "bad.csv" in err and "furlongs" in err


def test_probes_from_a_parameter_file(run_cli, export_run_folder, tmp_path):
    from napari_aldic.engine import DICParams, Settings
    from napari_aldic.engine.io import write_settings
    from napari_aldic.engine.probes import LineProbe, ProbeSet

    probes = ProbeSet()
    probes.lines.append(LineProbe(20, 64, 108, 64))
    settings = write_settings(tmp_path / "analysis.json",
                              Settings(DICParams(), probes=probes.to_dict()))
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    assert run_cli(["probe", export_run_folder, "--probes", settings, "-o", a])[0] == 0
    assert run_cli(["probe", export_run_folder, "--line", 20, 64, 108, 64, "-o", b])[0] == 0
    assert _rows(a)[1] == _rows(b)[1]  # the same gauge, the same numbers
