"""Result exports: CSV, MATLAB, VTU, DaVis text, PNG, GIF, MP4, PDF; units; parameters."""

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import scipy.io as sio
from PIL import Image

from napari_aldic.engine import (
    DICParams,
    EncoderNotFoundError,
    Settings,
    Units,
    compute_strain,
    export_report,
    export_result,
    load_run,
    read_settings,
    write_settings,
)
from napari_aldic.engine.io import (
    collect_frames,
    export_csv,
    export_davis,
    export_mat,
    export_vtu,
    load_mat,
    read_csv,
    read_vtu,
    result_cells,
)
from napari_aldic.engine.viz import (
    export_gif,
    export_mp4,
    export_png,
    field_figure,
    line_profile,
    report_page_count,
)

UM = Units(pixel_size=0.5, unit="µm", frame_interval=0.2, time_unit="s")

#: the names docs/exports.md promises in a .mat file
MAT_TOP = {"format", "format_version", "software", "pixel_size", "unit", "frame_interval",
           "time_unit", "frame", "time", "image_shape", "params_json", "params",
           "strain_settings", "reason_codes", "source", "untrusted_rule", "frames"}
MAT_FRAME = {"frame", "time", "x_px", "y_px", "u_px", "v_px", "x", "y", "u", "v", "magnitude",
             "vx", "vy", "dudx", "dudy", "dvdx", "dvdy", "zncc", "valid", "reason",
             "iterations", "grid_ix", "grid_iy", "grid_xs", "grid_ys", "exx", "eyy", "exy",
             "e1", "e2", "max_shear", "von_mises", "rotation", "exx_rate", "eyy_rate",
             "exy_rate", "strain_valid", "u_local", "v_local", "elements", "faces", "hanging",
             "meta_json", "u_attempt", "v_attempt", "u_std", "v_std", "sssig", "mig"}
RESULT_FIELDS = ("x", "y", "u", "v", "dudx", "dudy", "dvdx", "dvdy", "valid", "zncc", "reason",
                 "iterations", "grid_ix", "grid_iy", "grid_xs", "grid_ys", "u_local",
                 "v_local", "elements", "hanging", "roi")


def _equal(a, b):
    if a is None or b is None:
        return a is None and b is None
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


def _not_blank(img: Image.Image, min_ink=0.03, min_colour=0.01):
    a = np.asarray(img.convert("RGB")).astype(float)
    ink = (a.min(axis=-1) < 200).mean()  # not white paper
    colour = ((a.max(axis=-1) - a.min(axis=-1)) > 40).mean()  # coloured map pixels
    assert a.std() > 10, "image is uniform"
    assert ink > min_ink, f"only {ink:.1%} of the image is drawn"
    assert colour >= min_colour, f"only {colour:.1%} of the image is coloured"


# ------------------------------------------------------------------ units
def test_units_validate_and_describe():
    assert Units().describe().startswith("lengths in pixels")
    assert UM.velocity_unit == "µm/s" and UM.rate_unit == "1/s"
    assert UM.time(3) == pytest.approx(0.6)
    assert Units.from_dict(UM.to_dict()) == UM
    with pytest.raises(ValueError, match="physical length unit"):
        Units(pixel_size=2.0)  # 'px' with a pixel size != 1
    with pytest.raises(ValueError, match="pixel_size"):
        Units(pixel_size=-1, unit="um")
    with pytest.raises(ValueError, match="frame_interval"):
        Units(frame_interval=0)
    with pytest.raises(ValueError, match="unknown unit setting"):
        Units.from_dict({"pixel": 1})


def test_units_travel_with_the_result_meta(tmp_path, export_sequence):
    res = export_sequence[2]
    res2 = type(res)(**{**res.__dict__, "meta": {**res.meta, "units": UM.to_dict()}})
    path = res2.save(tmp_path / "r.npz")
    frames, units, _ = collect_frames(path)
    assert units == UM and frames[0].index == 2
    out = read_csv(export_csv(path, tmp_path / "r.csv"))
    assert out["units"]["u"] == "µm" and out["settings"] == UM


# ------------------------------------------------------------------ CSV
def test_csv_round_trip_with_units_rates_and_strain(tmp_path, export_sequence, export_stack):
    seq = export_sequence
    path = export_csv(seq, tmp_path / "seq.csv", units=UM)
    text = path.read_text(encoding="utf-8")
    assert "#" not in text  # a plain table: metadata in the JSON sidecar (issue 25)
    header_row = text.splitlines()[0]
    assert "u [µm]" in header_row and "vx [µm/s]" in header_row
    assert "exx_rate [1/s]" in header_row and "time [s]" in header_row
    assert "exx [1]" in header_row and "sssig [GL^2]" in header_row and "mig [GL/px]" in \
        header_row
    side = json.loads(path.with_suffix(".json").read_text(encoding="utf-8"))
    assert side["csv"] == "seq.csv" and side["settings"] == UM.to_dict()
    pd = pytest.importorskip("pandas")
    df = pd.read_csv(path)  # plain pandas reads it: one row per node per frame
    assert len(df) == len(export_stack) * len(seq[0]) and "u [µm]" in df.columns
    out = read_csv(path)
    cols, units = out["columns"], out["units"]
    assert units["x"] == "µm" and units["x_px"] == "px" and units["rotation"] == "rad"
    assert units["exx"] == "1" and units["vy"] == "µm/s" and units["frame"] == ""
    assert out["settings"] == UM
    n = len(seq[0])
    assert cols["frame"].size == len(export_stack) * n  # one row per node per frame
    prev = None
    for k in range(len(export_stack)):
        rows = cols["frame"] == k
        res = seq[k]
        np.testing.assert_allclose(cols["time"][rows], 0.2 * k)
        np.testing.assert_array_equal(cols["node"][rows], np.arange(n))
        np.testing.assert_array_equal(cols["x_px"][rows], res.x)
        np.testing.assert_allclose(cols["u"][rows], 0.5 * res.u, rtol=1e-9)
        np.testing.assert_allclose(cols["y"][rows], 0.5 * res.y, rtol=1e-9)
        np.testing.assert_array_equal(cols["valid"][rows], res.valid)
        np.testing.assert_array_equal(cols["reason"][rows], res.reason)
        np.testing.assert_allclose(cols["zncc"][rows], res.zncc, rtol=1e-9)
        s = compute_strain(res, window=5)
        np.testing.assert_allclose(cols["exx"][rows], s.exx, rtol=1e-8, atol=1e-12,
                                   equal_nan=True)
        if prev is None:
            assert np.isnan(cols["vx"][rows]).all()  # no velocity at the reference frame
        else:
            np.testing.assert_allclose(cols["vx"][rows], (res.u - prev[0].u) * 0.5 / 0.2,
                                       rtol=1e-8, atol=1e-12)
            np.testing.assert_allclose(cols["exx_rate"][rows], (s.exx - prev[1].exx) / 0.2,
                                       rtol=1e-7, atol=1e-10, equal_nan=True)
        prev = (res, s)
    # the applied field: mean exx of the last frame close to the truth
    last = cols["frame"] == len(export_stack) - 1
    assert np.nanmean(cols["exx"][last]) == pytest.approx(0.03, abs=2e-3)


def test_csv_without_strain_or_time(tmp_path, export_sequence):
    out = read_csv(export_csv(export_sequence[1], tmp_path / "one", strain=False))
    names = set(out["columns"])
    assert {"frame", "x", "u", "valid", "reason", "zncc"} <= names
    assert not names & {"time", "vx", "exx", "exx_rate"}
    assert out["units"]["u"] == "px"
    assert (tmp_path / "one.csv").exists()  # suffix added


# ------------------------------------------------------------------ MATLAB
def test_mat_is_readable_by_loadmat_with_documented_names(tmp_path, export_sequence, export_stack):
    seq = export_sequence
    path = export_mat(seq, tmp_path / "seq.mat", units=UM)
    d = sio.loadmat(path)
    assert MAT_TOP <= set(d)
    assert str(d["format"][0]) == "napari-aldic-mat"
    assert str(d["unit"][0]) == "µm" and float(d["pixel_size"][0, 0]) == 0.5
    assert float(d["frame_interval"][0, 0]) == 0.2
    np.testing.assert_array_equal(d["frame"].ravel(), np.arange(len(export_stack)))
    st = d["frames"]
    assert st.shape == (1, len(export_stack))
    assert set(st.dtype.names) == MAT_FRAME
    n = len(seq[0])
    for k in range(len(export_stack)):
        el = st[0, k]
        np.testing.assert_allclose(el["u"].ravel(), 0.5 * seq[k].u)
        np.testing.assert_array_equal(el["u_px"].ravel(), seq[k].u)
        np.testing.assert_array_equal(el["valid"].ravel().astype(bool), seq[k].valid)
    # same nodes in every frame: stacked F x N matrices at top level
    assert d["u"].shape == (len(export_stack), n) and d["x"].shape == (n, 1)
    np.testing.assert_allclose(d["u"][3], 0.5 * seq[3].u)
    assert d["exx"].shape == (len(export_stack), n)
    p = json.loads(str(d["params_json"][0]))
    assert DICParams.from_dict(p) == seq.params
    assert int(d["params"]["subset"][0, 0][0, 0]) == 21
    # full round trip back into the engine
    back = load_mat(path)
    assert len(back) == len(export_stack)
    for k in range(len(export_stack)):
        for name in RESULT_FIELDS:
            assert _equal(getattr(back[k], name), getattr(seq[k], name)), name
        assert back[k].params == seq.params and back[k].image_shape == seq[k].image_shape
        assert back[k].meta["frame"] == k


def test_mat_round_trip_of_an_aldic_quadtree_result(tmp_path, aldic_result):
    res = aldic_result
    back = load_mat(export_mat(res, tmp_path / "a.mat"))[0]
    for name in RESULT_FIELDS:
        assert _equal(getattr(back, name), getattr(res, name)), name
    d = sio.loadmat(tmp_path / "a.mat")
    faces = d["frames"][0, 0]["faces"]
    np.testing.assert_array_equal(faces, res.elements + 1)  # 1-based for MATLAB
    assert d["roi"].shape == res.image_shape
    # a .mat is itself an export input
    assert collect_frames(tmp_path / "a.mat")[0][0].result.n_valid == res.n_valid


# ------------------------------------------------------------------ VTK
@pytest.mark.parametrize("encoding", ["binary", "ascii"])
def test_vtu_of_a_lattice_result_parses_back(tmp_path, encoding, export_sequence):
    res = export_sequence[3]
    path = export_vtu(res, tmp_path / "r.vtu", units=UM, encoding=encoding)[0]
    root = ET.parse(path).getroot()
    assert root.tag == "VTKFile" and root.get("type") == "UnstructuredGrid"
    piece = root.find("UnstructuredGrid/Piece")
    gy, gx = res.grid_shape
    assert int(piece.get("NumberOfPoints")) == len(res) == gx * gy
    assert int(piece.get("NumberOfCells")) == (gx - 1) * (gy - 1)  # full-ROI lattice
    names = {da.get("Name") for da in piece.find("PointData")}
    assert {"displacement", "velocity", "u", "v", "exx", "eyy", "exy", "valid", "reason",
            "zncc"} <= names
    v = read_vtu(path)
    np.testing.assert_allclose(v["points"][:, 0], 0.5 * res.x, rtol=1e-12)
    np.testing.assert_allclose(v["point_data"]["u"], 0.5 * res.u, rtol=1e-12)
    np.testing.assert_allclose(v["point_data"]["displacement"][:, 1], 0.5 * res.v, rtol=1e-12)
    np.testing.assert_array_equal(v["point_data"]["valid"].astype(bool), res.valid)
    assert set(np.unique(v["types"])) == {9}  # VTK_QUAD
    np.testing.assert_array_equal(v["cells"], result_cells(res))
    assert v["field_data"]["TimeValue"][0] == pytest.approx(0.6)


def test_vtu_ascii_keeps_nan_readable(tmp_path, export_sequence):
    # frame 0 has no velocity (NaN): VTK cannot parse NaN in ASCII, so that array
    # stays base64 unless a fill value is given
    paths = export_vtu(export_sequence, tmp_path / "a.vtu", units=UM, encoding="ascii",
                       frames=[0, 1])
    root = ET.parse(paths[0]).getroot()
    fmt = {da.get("Name"): da.get("format")
           for da in root.find("UnstructuredGrid/Piece/PointData")}
    assert fmt["vx"] == "binary" and fmt["u"] == "ascii"
    assert np.isnan(read_vtu(paths[0])["point_data"]["vx"]).all()
    filled = export_vtu(export_sequence, tmp_path / "b.vtu", units=UM, encoding="ascii",
                        frames=[0, 1], nan_value=-999.0)
    v = read_vtu(filled[0])
    assert (v["point_data"]["vx"] == -999.0).all()
    assert 'format="binary"' not in filled[0].read_text()


def test_vtu_uses_the_aldic_mesh_and_sequences_get_a_pvd(tmp_path, aldic_result, export_sequence,
                                                         export_stack):
    res = aldic_result
    v = read_vtu(export_vtu(res, tmp_path / "a.vtu")[0])
    assert v["n_points"] == len(res) and v["n_cells"] == len(res.elements)
    np.testing.assert_array_equal(v["cells"], res.elements)
    paths = export_vtu(export_sequence, tmp_path / "s.vtu", units=UM, strain=False)
    assert len(paths) == len(export_stack) + 1 and paths[-1].suffix == ".pvd"
    sets = ET.parse(paths[-1]).getroot().findall("Collection/DataSet")
    assert [s.get("file") for s in sets] == [p.name for p in paths[:-1]]
    np.testing.assert_allclose([float(s.get("timestep")) for s in sets],
                               0.2 * np.arange(len(export_stack)))
    assert "exx" not in read_vtu(paths[1])["point_data"]


# ------------------------------------------------------------------ DaVis / DefDAP
def test_davis_text_has_the_layout_defdap_reads(tmp_path, export_sequence):
    res = export_sequence[2]
    path = export_davis(res, tmp_path / "d.txt")[0]
    first = path.read_text().splitlines()[0].split()
    assert first[0] == "#DaVis" and first[2] == "2D-vector"
    step, ydim, xdim = int(first[3]), int(first[4]), int(first[5])
    assert (step, ydim, xdim) == (12, *res.grid_shape)
    data = np.loadtxt(path, delimiter="\t", skiprows=1)
    assert data.shape == (xdim * ydim, 4)
    xc, yc = data[:, 0], data[:, 1]
    # DefDAP's own consistency check of the map size
    assert int((xc.max() - xc.min()) / min(abs(np.diff(xc))) + 1) == xdim
    assert int((yc.max() - yc.min()) / max(abs(np.diff(yc))) + 1) == ydim
    np.testing.assert_allclose(data[:, 2].reshape(ydim, xdim), res.to_grid("u"), rtol=1e-7)


# ------------------------------------------------------------------ images
def test_png_field_images_with_units_on_the_colour_bar(tmp_path, export_sequence, export_stack):
    seq = export_sequence
    paths = export_png(seq, tmp_path / "u.png", "u", units=UM, dpi=80)
    assert [p.name for p in paths] == [f"u_frame{k:05d}.png" for k in range(len(export_stack))]
    with Image.open(paths[-1]) as im:
        assert im.format == "PNG"
        _not_blank(im)
    one = export_png(seq, tmp_path / "exx", "exx", frames=[3], dpi=80)
    assert one == [tmp_path / "exx.png"]
    fig = field_figure(seq, "u", units=UM)
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert "u (µm)" in labels and "y (µm)" in labels
    fig = field_figure(seq, "exx_rate", units=UM)
    assert any("1/s" in ax.get_ylabel() for ax in fig.axes)
    with pytest.raises(ValueError, match="frame interval"):
        field_figure(seq, "vx")
    with pytest.raises(ValueError, match="unknown field"):
        export_png(seq, tmp_path / "bad.png", "speed")


def test_gif_has_one_frame_per_result_frame(tmp_path, export_sequence, export_stack):
    path = export_gif(export_sequence, tmp_path / "u.gif", "v", units=UM, fps=5, dpi=60)
    with Image.open(path) as im:
        assert im.n_frames == len(export_stack)
        assert im.info["duration"] == 200
        im.seek(len(export_stack) - 1)
        _not_blank(im)


def test_mp4_has_one_frame_per_result_frame(tmp_path, export_sequence, export_stack):
    import imageio_ffmpeg
    path = export_mp4(export_sequence, tmp_path / "u.mp4", "u", fps=4, dpi=60)
    gen = imageio_ffmpeg.read_frames(str(path))
    meta = next(gen)
    assert meta["fps"] == pytest.approx(4)
    assert sum(1 for _ in gen) == len(export_stack)


def test_missing_video_encoder_gives_advice_and_gif_still_works(tmp_path, monkeypatch,
                                                                export_sequence):
    import sys

    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # as if not installed
    with pytest.raises(EncoderNotFoundError, match="pip install imageio-ffmpeg") as info:
        export_mp4(export_sequence, tmp_path / "u.mp4")
    assert "GIF" in str(info.value)
    assert not (tmp_path / "u.mp4").exists()
    assert export_gif(export_sequence, tmp_path / "u.gif", dpi=50).exists()


def test_colour_limits_modes():
    from napari_aldic.engine.viz import colour_limits, field_colour_limits

    v = np.r_[np.linspace(-1.0, 2.0, 1001), np.nan, np.inf]
    lo, hi = colour_limits(v)  # robust 0.5 .. 99.5 % range of the finite values
    assert -1.0 < lo < -0.98 and 1.98 < hi < 2.0
    assert colour_limits([v[:500], v[500:]]) == (lo, hi)  # frames share one range
    assert colour_limits(v, "symmetric") == (-hi, hi)
    assert colour_limits(v, "symmetric", percentile=100) == (-2.0, 2.0)
    assert colour_limits(v, "from_zero") == (0.0, hi)
    assert colour_limits(np.zeros(5), "symmetric") == (-1e-9, 1e-9)
    assert colour_limits(np.zeros(5), "symmetric", fallback=1.0) == (-1.0, 1.0)
    assert colour_limits(np.full(3, np.nan), "symmetric") == (-1.0, 1.0)
    assert colour_limits([], "from_zero") == (0.0, 1.0)
    with pytest.raises(ValueError, match="mode"):
        colour_limits(v, "log")
    assert field_colour_limits("u", [v]) == ("RdBu_r", -hi, hi)
    assert field_colour_limits("magnitude", [v])[0] == "viridis"
    assert field_colour_limits("u", [v], clim=(-0.5, 1.0)) == ("RdBu_r", -0.5, 1.0)
    assert field_colour_limits("zncc", [np.full(4, 0.999)]) == ("viridis", 0.99, 1.0)


# ------------------------------------------------------------------ PDF report
@pytest.mark.slow  # ~6 s
def test_pdf_report_pages_and_rendering(tmp_path, export_run_folder, export_sequence, export_stack):
    import pypdfium2 as pdfium
    seq = export_sequence
    line = (10.0, 64.0, 118.0, 64.0)
    path = export_report(seq, tmp_path / "report.pdf", units=UM, frames=[1, 3], line=line,
                         image=export_stack[0])
    pdf = pdfium.PdfDocument(str(path))
    try:
        assert len(pdf) == report_page_count(2, line=True) == 7
        for page in (0, 2, 4):  # parameters, maps of frame 1, line profiles
            img = pdf[page].render(scale=0.8).to_pil()
            _not_blank(img, min_colour=0.0 if page == 0 else 0.01)
    finally:
        pdf.close()
    # default frame choice, no line, from a run folder on disk
    path2 = export_report(export_run_folder, tmp_path / "r2.pdf", strain=False)
    pdf = pdfium.PdfDocument(str(path2))
    try:
        assert len(pdf) == report_page_count(len(export_stack) - 1, line=False)
    finally:
        pdf.close()


def test_line_profile_follows_the_applied_field(export_field, export_sequence):
    fr = collect_frames(export_sequence, frames=[3], units=UM)[0][0]
    dist, prof = line_profile(fr, UM, (20, 40, 100, 40), names=("u", "exx"))
    assert dist[-1] == pytest.approx(40.0)  # 80 px * 0.5 um
    ut, _ = export_field(3).displacement(20 + dist / UM.pixel_size, np.full(dist.shape, 40.0))
    np.testing.assert_allclose(prof["u"], ut * 0.5, atol=0.02)
    np.testing.assert_allclose(prof["exx"], 0.03, atol=2e-3)
    with pytest.raises(ValueError, match="same point"):
        line_profile(fr, UM, (1, 1, 1, 1))


# ------------------------------------------------------------------ run folders and dispatch
def test_run_folder_and_cli_style_folders_load(tmp_path, export_run_folder, export_sequence,
                                               export_stack):
    seq = load_run(export_run_folder)
    assert len(seq) == len(export_stack) and seq.complete  # frame 0 (zero field) is written too
    assert np.all(seq[0].u == 0)
    for k in range(1, len(export_stack)):
        np.testing.assert_array_equal(seq[k].u, export_sequence[k].u)
    folder = tmp_path / "cli_run"
    folder.mkdir()
    for k in (1, 2, 10):
        export_sequence[min(k, 3)].save(folder / f"frame{k:03d}.npz")
    frames, _, _ = collect_frames(folder, strain=False)
    assert [f.index for f in frames] == [1, 2, 3]  # frame numbers stored in the results
    out = export_result(export_run_folder, tmp_path / "x.csv", units=UM)
    assert set(read_csv(out)["columns"]["frame"]) == {0, 1, 2, 3}
    with pytest.raises(ValueError, match="export format"):
        export_result(seq, tmp_path / "x.xyz")


# ------------------------------------------------------------------ parameters
def test_parameters_save_and_load(tmp_path):
    p = DICParams(subset=25, step=10, method="aldic", seeds=((10.0, 20.0),), refine="light")
    path = write_settings(tmp_path / "analysis", Settings(p, UM, {"window": 7},
                                                          {"reference": "incremental"}))
    assert path.name == "analysis.json"
    doc = json.loads(path.read_text(encoding="utf-8"))
    assert doc["params"]["subset"] == 25 and doc["units"]["unit"] == "µm"
    s = read_settings(path)
    assert s.params == p and s.units == UM
    assert s.strain_options() == {"window": 7, "method": "plane_fit",
                                  "measure": "green_lagrange"}
    assert s.tracking == {"reference": "incremental"}
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps(p.to_dict()))
    assert read_settings(plain).params == p
    plain.write_text(json.dumps({"subset": 21, "bogus": 1}))
    with pytest.raises(ValueError, match="bogus"):
        read_settings(plain)
