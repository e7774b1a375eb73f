"""Probes against exact truth: line gauges, crack opening, points, areas, profiles,
statuses, and the testing-machine load reader and synchronisation."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from napari_aldic.engine import Reason, Units, correlate, synthetic as S, track
from napari_aldic.engine.probes import (
    DEGRADED,
    MISSING,
    OK,
    AreaProbe,
    FrameSampler,
    LineProbe,
    PointProbe,
    ProbeSet,
    attach_load,
    export_kymograph_csv,
    export_probe_plot,
    export_probes_csv,
    kymograph,
    load_at_frames,
    measure_probes,
    read_load_csv,
)

#: set to write the pictures of docs/probes.md into docs/images
DOC_IMAGES = Path(__file__).resolve().parents[2] / "docs" / "images" if os.environ.get(
    "NAPARI_ALDIC_DOC_IMAGES", "") not in ("", "0") else None
SHAPE = (160, 160)
CENTER = (80.0, 80.0)
EXX = np.linspace(0.0, 0.02, 5)  # frame k: exx = EXX[k]
ANGLE = np.linspace(0.0, 0.4, 5)  # and a small rigid rotation (degrees)


def _strain_field(k: int):
    return S.Affine.strain_rotation(exx=EXX[k], angle_deg=ANGLE[k], center=CENTER,
                                    t=(0.2 * k, -0.1 * k))


@pytest.fixture(scope="module")
def strain_run():
    """Uniform strain exx 0 -> 2 % over 5 frames, tracked (local IC-GN)."""
    pat = S.make_pattern(SHAPE, seed=3, margin=32)
    stack = np.stack([S.render(pat, SHAPE, None if k == 0 else _strain_field(k), n_quad=2)
                      for k in range(EXX.size)])
    return track(stack, subset=21, step=8)


def _gauge_truth(field, line: LineProbe):
    """(strain, elongation, opening, sliding) of the exact field at the gauge points."""
    u, v = field.displacement(np.array([line.x0, line.x1]), np.array([line.y0, line.y1]))
    d = np.array([u[1] - u[0], v[1] - v[0]])
    chord = np.array([line.x1 - line.x0, line.y1 - line.y0]) + d
    ell = np.hypot(*chord)
    return (ell - line.length) / line.length, ell - line.length, d @ line.direction, \
        d @ line.normal


# ------------------------------------------------------------------ line gauges
def test_line_gauge_strain_is_exact_at_every_frame(strain_run):
    lines = [LineProbe(30, 80, 130, 80), LineProbe(35, 45, 125, 115)]
    table = measure_probes(strain_run, ProbeSet(lines=lines))
    assert list(table.frames) == list(range(EXX.size))
    for i, line in enumerate(lines, 1):
        truth = np.array([_gauge_truth(_strain_field(k), line) for k in range(EXX.size)])
        strain = table[f"line{i}_strain"]
        assert np.abs(strain - truth[:, 0]).max() < 1e-4, (strain, truth[:, 0])
        np.testing.assert_allclose(table[f"line{i}_true_strain"], np.log1p(strain), atol=1e-12)
        assert np.abs(table[f"line{i}_elongation"] - truth[:, 1]).max() < 0.01
        assert np.abs(table[f"line{i}_cod_opening"] - truth[:, 2]).max() < 0.01
        assert np.abs(table[f"line{i}_cod_sliding"] - truth[:, 3]).max() < 0.01
        np.testing.assert_allclose(table[f"line{i}_cod_magnitude"],
                                   np.hypot(table[f"line{i}_cod_opening"],
                                            table[f"line{i}_cod_sliding"]), atol=1e-12)
        for name in (f"line{i}_strain", f"line{i}_cod_opening"):
            assert table.columns[name].status_text == ["ok"] * EXX.size
    # the horizontal gauge sees exx itself; the rotation shows as sliding, not strain
    assert abs(table["line1_strain"][-1] - 0.02) < 1e-4
    assert table["line1_cod_sliding"][-1] > 0.5 * np.deg2rad(ANGLE[-1]) * lines[0].length
    # frame 0 is the reference: exactly zero
    assert all(table[n][0] == 0 for n in table.columns)


def test_lengths_are_in_the_runs_unit(strain_run):
    line = LineProbe(30, 80, 130, 80)
    px = measure_probes(strain_run, ProbeSet(lines=[line]))
    um = measure_probes(strain_run, ProbeSet(lines=[line]), units=Units(0.5, "um"))
    assert um.columns["line1_elongation"].unit == "um"
    np.testing.assert_allclose(um["line1_elongation"], 0.5 * px["line1_elongation"])
    np.testing.assert_allclose(um["line1_cod_opening"], 0.5 * px["line1_cod_opening"])
    np.testing.assert_array_equal(um["line1_strain"], px["line1_strain"])


@pytest.fixture(scope="module")
def crack_run():
    """A Mode-I crack opening over three frames, crack excluded from the ROI."""
    shape, tip = (160, 240), (170.0, 80.0)
    fields = [None] + [S.ModeICrack(tip=tip, amplitude=a, t=(0.3, 0.2)) for a in (0.03, 0.06)]
    pat = S.make_pattern(shape, seed=5, margin=32)
    stack = np.stack([S.render(pat, shape, f, n_quad=2) for f in fields])
    seq = track(stack, roi=S.crack_roi(shape, tip), subset=21, step=6)
    return seq, fields


def test_crack_opening_across_the_crack_matches_the_analytic_opening(crack_run):
    seq, fields = crack_run
    xs, y, d = (40.0, 70.0, 100.0, 120.0), 80.0, 8.0
    lines = [LineProbe(x, y - d, x, y + d) for x in xs]  # across the crack, e = +y
    table = measure_probes(seq, ProbeSet(lines=lines))
    for i, line in enumerate(lines, 1):
        cod = table[f"line{i}_cod_opening"]
        truth = np.array([0.0] + [_gauge_truth(f, line)[2] for f in fields[1:]])
        faces = np.array([0.0] + [f.opening(line.x0) for f in fields[1:]])
        assert faces[-1] > 2.0  # the crack opens by pixels
        assert np.abs(cod - truth).max() < 0.02, (line, cod, truth)
        assert np.abs(cod - faces).max() < 0.02, (line, cod, faces)
        assert table.columns[f"line{i}_cod_opening"].status_text == ["ok"] * 3
        # the gauge strain includes the opening: flagged, with the reason
        st = table.columns[f"line{i}_strain"]
        assert list(st.status[1:]) == [DEGRADED, DEGRADED]
        assert "crack or hole" in st.reasons[-1]


# ------------------------------------------------------------------ points and areas
def test_point_probe_interpolates_between_nodes(strain_run):
    pts = [PointProbe(63.3, 97.7), PointProbe(101.5, 52.25)]
    table = measure_probes(strain_run, ProbeSet(points=pts), fields=("u", "v", "exx"))
    for i, p in enumerate(pts, 1):
        u, v = np.array([_strain_field(k).displacement(p.x, p.y) for k in range(EXX.size)]).T
        assert np.abs(table[f"point{i}_u"] - u).max() < 0.01
        assert np.abs(table[f"point{i}_v"] - v).max() < 0.01
        gl = EXX + 0.5 * EXX**2  # Green-Lagrange strain of the stretch (rotation free)
        assert np.abs(table[f"point{i}_exx"] - gl).max() < 5e-4
        assert table.columns[f"point{i}_u"].unit == "px"


def test_area_statistics_are_those_of_the_nodes_inside(strain_run):
    area = AreaProbe.rectangle(40, 40, 120, 110)
    table = measure_probes(strain_run, ProbeSet(areas=[area]), fields=("u", "exx"))
    res = strain_run[4]
    inside = area.contains(res.x, res.y)
    u = res.u[inside & res.valid]
    assert 50 < inside.sum() < res.x.size
    assert table["area1_u_mean"][4] == pytest.approx(u.mean(), abs=1e-12)
    assert table["area1_u_median"][4] == pytest.approx(np.median(u), abs=1e-12)
    assert table["area1_u_min"][4] == pytest.approx(u.min(), abs=1e-12)
    assert table["area1_u_max"][4] == pytest.approx(u.max(), abs=1e-12)
    assert table["area1_u_std"][4] == pytest.approx(u.std(), abs=1e-12)
    assert table["area1_u_valid_fraction"][4] == pytest.approx(u.size / inside.sum())
    assert abs(table["area1_exx_mean"][4] - (0.02 + 0.5 * 0.02**2)) < 3e-4


def test_area_shapes_contain_the_right_points():
    x, y = np.meshgrid(np.arange(0, 21.0), np.arange(0, 21.0))
    circle = AreaProbe.circle(10, 10, 5)
    assert circle.contains(x, y).sum() == np.count_nonzero(np.hypot(x - 10, y - 10) <= 5)
    ell = AreaProbe.ellipse(10, 10, 8, 2, angle_deg=90)  # long axis along y
    assert ell.contains(10, 17) and not ell.contains(17, 10)
    tri = AreaProbe.polygon([(0, 0), (20, 0), (0, 20)])
    assert tri.contains(x, y).sum() == np.count_nonzero(x + y <= 20)
    rect = AreaProbe.rectangle(12, 8, 2, 3)  # corners in any order
    assert rect.params == (2.0, 3.0, 12.0, 8.0) and rect.contains(2, 8)


# ------------------------------------------------------------------ statuses
def test_missing_values_carry_their_reason_and_are_never_zero(strain_run):
    res = strain_run[4]
    roi = np.ones(SHAPE, bool)
    roi[70:90, 70:90] = False  # a hole
    holed = replace(res, roi=roi)
    bad = (np.abs(res.x - 40) < 20) & (np.abs(res.y - 120) < 20)  # no trusted node near
    flagged = replace(holed, valid=res.valid & ~bad,
                      reason=np.where(bad, int(Reason.LOW_CORRELATION), res.reason))
    smp = FrameSampler(flagged)
    pts = {"hole": (80, 80), "outside": (170, 20), "flagged": (40, 120),
           "edge": (1.5, 40.0), "corner": (1.0, 1.0), "inside": (100.3, 40.6)}
    s = smp.sample(flagged.u, *np.array(list(pts.values())).T)
    got = dict(zip(pts, zip(s.values, s.status, s.reasons)))
    assert got["hole"][1] == MISSING and "outside the ROI" in got["hole"][2]
    assert got["outside"][1] == MISSING and "outside the image" in got["outside"][2]
    assert got["flagged"][1] == MISSING and "low correlation" in got["flagged"][2]
    assert got["edge"][1] == DEGRADED and "extrapolated" in got["edge"][2]
    assert got["corner"][1] == MISSING and "outside the measured field" in got["corner"][2]
    assert got["inside"][1] == OK and got["inside"][2] == ""
    for key in ("hole", "outside", "flagged", "corner"):
        assert np.isnan(got[key][0])
    u_true = _strain_field(4).displacement(1.5, 40.0)[0]
    assert abs(got["edge"][0] - u_true) < 0.02  # extrapolated, but close


def test_point_that_leaves_the_field_is_reported():
    shape = (128, 128)
    pat = S.make_pattern(shape, seed=9, margin=48)
    stack = np.stack([S.render(pat, shape, S.Translation(7.0 * k, 0.0), n_quad=2)
                      for k in range(4)])
    seq = track(stack, subset=21, step=8)
    table = measure_probes(seq, ProbeSet(points=[PointProbe(112.0, 64.0),
                                                 PointProbe(40.0, 64.0)]), fields=("u",))
    gone = table.columns["point1_u"]
    assert gone.status[0] == OK and gone.status[-1] == MISSING
    assert "left the field of view" in gone.reasons[-1]
    assert np.isnan(gone.values[-1])
    kept = table.columns["point2_u"]
    assert list(kept.status) == [OK] * 4
    assert np.abs(kept.values - 7.0 * np.arange(4)).max() < 0.01


def test_sparse_area_is_degraded(strain_run):
    res = strain_run[3]
    area = AreaProbe.rectangle(40, 40, 120, 120)
    inside = area.contains(res.x, res.y)
    drop = inside & (np.cumsum(inside) % 3 != 0)  # two nodes of three untrusted
    sparse = replace(res, valid=res.valid & ~drop, meta={**res.meta, "frame": 3})
    table = measure_probes([sparse], ProbeSet(areas=[area]), fields=("u",))
    col = table.columns["area1_u_mean"]
    assert col.status[-1] == DEGRADED and "trusted" in col.reasons[-1]
    assert table["area1_u_valid_fraction"][-1] == pytest.approx(
        np.count_nonzero(inside & ~drop & res.valid) / inside.sum())


# ------------------------------------------------------------------ inputs and outputs
def test_run_folder_and_result_file_give_frame_zero(export_run_folder, export_field, tmp_path):
    line = LineProbe(20, 64, 108, 64)
    table = measure_probes(export_run_folder, ProbeSet(lines=[line]))
    assert list(table.frames) == [0, 1, 2, 3]
    for k in range(1, 4):
        assert abs(table["line1_strain"][k] - _gauge_truth(export_field(k), line)[0]) < 2e-4
    # a single result file (no frame 0 stored): frame 0 is added as the zero field
    from napari_aldic.engine import load_result

    res = load_result(export_run_folder / "frame_00002.npz")
    path = res.save(tmp_path / "pair.npz")
    one = measure_probes(path, ProbeSet(lines=[line], points=[PointProbe(64, 64)]))
    assert list(one.frames) == [0, 2]
    assert one["line1_strain"][0] == 0 and one["point1_exx"][0] == 0
    assert one["line1_strain"][1] == pytest.approx(table["line1_strain"][2])


def test_probe_csv_is_one_row_per_frame_with_units_beside(strain_run, tmp_path):
    import json

    import pandas as pd

    probes = ProbeSet(lines=[LineProbe(30, 80, 130, 80)], points=[PointProbe(400, 80)])
    table = measure_probes(strain_run, probes, fields=("u",), units=Units(2.0, "um"))
    path = export_probes_csv(table, tmp_path / "probes.csv")
    df = pd.read_csv(path)
    assert list(df.columns[:7]) == ["frame", "line1_strain", "line1_true_strain",
                                    "line1_elongation", "line1_cod_opening",
                                    "line1_cod_sliding", "line1_cod_magnitude"]
    assert len(df) == EXX.size and list(df["frame"]) == list(range(EXX.size))
    np.testing.assert_allclose(df["line1_strain"], table["line1_strain"], rtol=1e-9)
    # the point is outside the image: empty cells, status and reason, never 0
    assert df["point1_u"].isna().all() and set(df["point1_status"]) == {"missing"}
    assert df["point1_reason"].str.contains("outside the image").all()
    meta = json.loads(path.with_suffix(".json").read_text())
    assert meta["units"]["line1_elongation"] == "um" and meta["units"]["line1_strain"] == ""
    assert ProbeSet.from_dict(meta["probes"]) == probes


def test_kymograph_follows_the_field(strain_run, tmp_path):
    kymo = kymograph(strain_run, [(30, 70), (90, 70), (130, 100)], "u", spacing=2.0)
    assert kymo.values.shape == (EXX.size, kymo.x.size)
    for k in range(EXX.size):
        u = _strain_field(k).displacement(kymo.x, kymo.y)[0]
        assert np.nanmax(np.abs(kymo.values[k] - u)) < 0.01
    assert np.all(kymo.status == OK)
    assert kymo.distance[-1] == pytest.approx(60 + 50)
    path = export_kymograph_csv(kymo, tmp_path / "kymo.csv")
    data = np.loadtxt(path, delimiter=",", skiprows=1)  # a plain table (issue 25)
    np.testing.assert_allclose(data[:, 3:], kymo.values.T, rtol=1e-8, atol=1e-12)
    head = path.read_text().splitlines()[0]
    assert head.startswith("distance [px],x_px [px],y_px [px],frame_0 [px]")
    if DOC_IMAGES is not None:
        from napari_aldic.engine.probes import export_kymograph_plot

        export_kymograph_plot(kymo, DOC_IMAGES / "probes_kymograph.png", dpi=80)


def test_probe_plot_shows_curves(strain_run, tmp_path):
    import matplotlib.image as mpimg

    table = measure_probes(strain_run, ProbeSet(lines=[LineProbe(30, 80, 130, 80)],
                                                areas=[AreaProbe.circle(80, 80, 35)]),
                           fields=("exx",))
    load = tmp_path / "load.csv"  # a linear-elastic test: 210 GPa, 20 mm²
    load.write_text("Frame;Load\n(-);(kN)\n" + "".join(
        f"{k};{210e3 * 20 * e / 1e3:.6f}\n".replace(".", ",") for k, e in enumerate(EXX)))
    attach_load(table, read_load_csv(load), area_mm2=20.0)
    assert np.abs(table["stress_MPa"] - 210e3 * EXX).max() < 1e-3
    png = export_probe_plot(table, tmp_path / "curves.png", dpi=60)
    if DOC_IMAGES is not None:
        export_probe_plot(table, DOC_IMAGES / "probes_curves.png", dpi=80)
    img = mpimg.imread(png)
    assert img.shape[0] > 100 and img[..., :3].std() > 0.05  # not blank
    assert export_probe_plot(table, tmp_path / "curves.pdf").read_bytes()[:4] == b"%PDF"


def test_probe_set_round_trip_and_bad_probes():
    probes = ProbeSet(points=[PointProbe(1, 2, "a")], lines=[LineProbe(0, 0, 3, 4)],
                      areas=[AreaProbe.circle(5, 5, 2), AreaProbe.polygon([(0, 0), (4, 0),
                                                                            (0, 3)])])
    assert ProbeSet.from_dict(probes.to_dict()) == probes
    assert probes.lines[0].length == 5
    with pytest.raises(ValueError, match="same"):
        LineProbe(1, 1, 1, 1)
    with pytest.raises(ValueError, match="finite"):
        PointProbe(np.nan, 1)
    with pytest.raises(ValueError, match="probe 1"):
        ProbeSet.from_dict({"probes": [{"kind": "blob"}]})
    with pytest.raises(ValueError, match="unknown field"):
        measure_probes([], probes, fields=("speed",))


# ------------------------------------------------------------------ load data
LOAD_T = np.round(np.arange(0.0, 2.01, 0.25), 4)
LOAD_N = 1000.0 * LOAD_T**2 + 5.0  # newtons


def _fmt(v: float, comma: bool) -> str:
    s = f"{v:g}"
    return s.replace(".", ",") if comma else s


DIALECTS = {
    # name: (separator, decimal comma, title, units row, load header, load scale)
    "comma_plain": (",", False, None, None, "Force", 1.0),
    "semicolon_decimal_comma_kN": (";", True, "Zwick export 2024-01-05", ["(s)", "(kN)", ""],
                                   "Standard force", 1e-3),
    "tab_units_in_header": ("\t", True, None, None, "Load [kN]", 1e-3),
    "comma_title_and_units_N": (",", False, "Specimen 3, tension", ["s", "N", "-"], "Load",
                                1.0),
}


def _write_load(path, dialect, frames=None):
    sep, comma, title, units, load_name, scale = DIALECTS[dialect]
    rows = [] if title is None else [title]
    rows.append(sep.join(["Time", load_name, "Frame"]))
    if units is not None:
        rows.append(sep.join(units))
    frames = np.arange(LOAD_T.size) if frames is None else frames
    for t, f, k in zip(LOAD_T, LOAD_N, frames):
        rows.append(sep.join([_fmt(t, comma), _fmt(f * scale, comma), str(int(k))]))
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


@pytest.mark.parametrize("dialect", list(DIALECTS))
def test_each_load_dialect_parses_to_the_same_loads(dialect, tmp_path):
    rec = read_load_csv(_write_load(tmp_path / f"{dialect}.csv", dialect))
    np.testing.assert_allclose(rec.load_N, LOAD_N, rtol=1e-9)
    np.testing.assert_allclose(rec.time_s, LOAD_T, rtol=1e-12)
    np.testing.assert_array_equal(rec.frame, np.arange(LOAD_T.size))


def test_german_export_with_compound_names_bom_and_crlf(tmp_path):
    # testXpert in German: "Standardkraft", "Prüfzeit"; Excel adds a BOM and CRLF
    path = tmp_path / "de.csv"
    path.write_bytes("\ufeffPrüfung 7\r\nPrüfzeit;Standardkraft;Dehnung\r\ns;kN;%\r\n"
                     "0,0;0,005;0\r\n0,5;1,25;0,1\r\n1,0;2,5;0,2\r\n".encode("utf-8"))
    rec = read_load_csv(path)
    assert rec.columns["load"] == "Standardkraft" and rec.columns["time"] == "Prüfzeit"
    np.testing.assert_allclose(rec.load_N, [5.0, 1250.0, 2500.0], rtol=1e-12)
    np.testing.assert_allclose(rec.time_s, [0.0, 0.5, 1.0], rtol=1e-12)


def test_time_sync_interpolates_and_never_extrapolates(tmp_path):
    rec = read_load_csv(_write_load(tmp_path / "l.csv", "comma_plain"))
    frames = np.arange(7)
    fps, offset = 2.0, -0.15  # frame k at k/2 - 0.15 s: between the 0.25 s samples
    load, status, reasons = load_at_frames(rec, frames, sync="time", fps=fps, offset=offset)
    t = frames / fps + offset
    inside = (t >= 0) & (t <= 2.0)
    assert list(inside) == [False, True, True, True, True, False, False]
    np.testing.assert_allclose(load[inside], np.interp(t[inside], LOAD_T, LOAD_N))
    # linear between the samples (t = 0.35 s: 40 % of the way from 0.25 s to 0.5 s)
    assert abs(load[1] - (LOAD_N[1] + 0.4 * (LOAD_N[2] - LOAD_N[1]))) < 1e-9
    assert abs(load[1] - (1000 * 0.35**2 + 5)) > 10  # not the curve through them
    assert np.all(np.isnan(load[~inside])) and np.all(status[~inside] == MISSING)
    assert list(status[inside]) == [OK] * 4
    assert "outside the load record" in reasons[0] and "-0.15" in reasons[0]


def test_frame_sync_averages_repeated_frames_and_gives_stress(strain_run, tmp_path):
    frames = np.array([0, 0, 1, 1, 2, 2, 3, 3, 3])  # several samples per image
    rec = read_load_csv(_write_load(tmp_path / "l.csv", "semicolon_decimal_comma_kN", frames))
    table = measure_probes(strain_run, ProbeSet(lines=[LineProbe(30, 80, 130, 80)]))
    attach_load(table, rec, area_mm2=20.0)
    expect = [LOAD_N[frames == k].mean() for k in range(4)]
    np.testing.assert_allclose(table["load_N"][:4], expect)
    np.testing.assert_allclose(table["stress_MPa"][:4], np.array(expect) / 20.0)
    assert np.isnan(table["load_N"][4])  # frame 4 is after the last recorded frame
    assert table.columns["stress_MPa"].status[4] == MISSING
    with pytest.raises(ValueError, match="area"):
        attach_load(table, rec, area_mm2=0)


def test_bad_load_files_name_the_file_and_the_problem(tmp_path):
    p = tmp_path / "noload.csv"
    p.write_text("Time,Strain\n0,0\n1,0.1\n2,0.2\n")
    with pytest.raises(ValueError, match="noload.csv.*no load column"):
        read_load_csv(p)
    q = tmp_path / "unit.csv"
    q.write_text("Time,Force\ns,tons\n0,0\n1,1\n2,2\n")
    with pytest.raises(ValueError, match="unit.csv.*unknown load unit 'tons'"):
        read_load_csv(q)
    rec = read_load_csv(_write_load(tmp_path / "l.csv", "comma_plain"))
    with pytest.raises(ValueError, match="fps"):
        load_at_frames(rec, [0, 1], sync="time")


def test_a_single_pair_result_works(tmp_path):
    ref, dfm = S.speckle_pair((96, 96), S.Translation(0.4, -0.3), seed=2, n_quad=2)
    res = correlate(ref, dfm, subset=21, step=8)
    table = measure_probes(res, ProbeSet(lines=[LineProbe(20, 48, 76, 48)]))
    assert list(table.frames) == [0, 1]
    assert abs(table["line1_strain"][1]) < 1e-4


def test_report_gets_a_probe_page(export_sequence, export_stack, tmp_path):
    import re

    from napari_aldic.engine import export_report
    from napari_aldic.engine.viz import report_page_count

    load = tmp_path / "l.csv"
    load.write_text("Frame,Load (kN)\n0,0\n1,1\n2,2\n3,3\n")
    table = measure_probes(export_sequence, ProbeSet(lines=[LineProbe(20, 64, 108, 64)],
                                                     areas=[AreaProbe.circle(64, 64, 30)]))
    attach_load(table, read_load_csv(load), area_mm2=5.0)
    pdf = export_report(export_sequence, tmp_path / "r.pdf", frames=[3], probes=table,
                        image=export_stack[0])
    n_pages = len(re.findall(rb"/Type\s*/Page(?!s)", pdf.read_bytes()))
    assert n_pages == report_page_count(1, False, len(export_stack)) + 1
    from napari_aldic.engine.viz.probe_page import probe_page

    fig = probe_page(table)
    fig.savefig(tmp_path / "probe_page.png", dpi=60)
    assert len(fig.axes) == 4  # strains, lengths, load, stress-strain


def test_probes_on_an_aldic_quadtree_result(aldic_result, export_field):
    """Quadtree cells (hanging nodes) and a hole in the ROI."""
    res = replace(aldic_result, meta={**aldic_result.meta, "frame": 2})
    pts = [PointProbe(30.5, 33.2), PointProbe(95.3, 70.1), PointProbe(64.0, 64.0)]
    table = measure_probes(res, ProbeSet(points=pts, lines=[LineProbe(20, 64, 108, 64)]),
                           fields=("u", "v"))
    for i, p in enumerate(pts[:2], 1):
        u, v = export_field(2).displacement(p.x, p.y)
        assert abs(table[f"point{i}_u"][1] - u) < 0.02
        assert abs(table[f"point{i}_v"][1] - v) < 0.02
    hole = table.columns["point3_u"]
    assert hole.status[1] == MISSING and "outside the ROI" in hole.reasons[1]
    field = export_field(2)
    u, v = field.displacement(np.array([20.0, 108.0]), np.array([64.0, 64.0]))
    assert abs(table["line1_strain"][1] - (np.hypot(88 + u[1] - u[0], v[1] - v[0]) / 88 - 1)) \
        < 3e-4
    # the gauge spans the hole: its strain is flagged, its opening is not
    assert table.columns["line1_strain"].status[1] == DEGRADED
    assert table.columns["line1_cod_opening"].status[1] == OK
