"""The ``napari-aldic`` command line: demo, run (pair, stack, folder), errors."""

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile

from napari_aldic import __version__
from napari_aldic.engine import load_result, synthetic as S
from napari_aldic.engine.synthetic import make_field

DEMO_SIZE = 128




@pytest.fixture(scope="module")
def demo(run_cli, tmp_path_factory):
    """One small demo run shared by the tests: (folder, stdout)."""
    folder = tmp_path_factory.mktemp("demo") / "out"
    rc, out, err = run_cli(["demo", "--out", folder, "--size", DEMO_SIZE])
    assert rc == 0, err
    return folder, out


@pytest.fixture(scope="module")
def stack_case(tmp_path_factory):
    """A 3-page TIFF stack: reference, translated, uniformly strained."""
    shape = (128, 128)
    fields = [S.Translation(0.3, -0.2), S.Translation(-1.4, 0.7)]
    pat = S.make_pattern(shape, seed=11)
    frames = [S.render(pat, shape)] + [S.render(pat, shape, f) for f in fields]
    path = tmp_path_factory.mktemp("stack") / "stack.tif"
    tifffile.imwrite(path, np.stack(frames), photometric="minisblack")
    return path, frames, fields


# ----------------------------------------------------------------- demo
def test_demo_reports_small_error_and_writes_files(demo):
    folder, out = demo
    for name in ("reference.tif", "deformed.tif", "result.npz", "params.json",
                 "displacement.png"):
        assert (folder / name).is_file(), name
    assert str(folder.resolve()) in out

    # the reported errors are real numbers below 0.02 px
    rep = {c: (float(a), float(b)) for c, a, b in
           re.findall(r"(u|v): RMSE ([0-9.]+) px, max ([0-9.]+) px", out)}
    assert set(rep) == {"u", "v"}
    assert rep["u"][0] < 0.02 and rep["v"][0] < 0.02

    # recompute them from the saved result and the exact field
    res = load_result(folder / "result.npz")
    field, _ = make_field("strain", (DEMO_SIZE, DEMO_SIZE))
    ut, vt = field.displacement(res.x, res.y)
    sel = res.valid
    assert sel.sum() >= 0.9 * len(res)
    rmse_u = np.sqrt(np.mean((res.u[sel] - ut[sel]) ** 2))
    rmse_v = np.sqrt(np.mean((res.v[sel] - vt[sel]) ** 2))
    assert rmse_u < 0.02 and rmse_v < 0.02
    assert rmse_u == pytest.approx(rep["u"][0], abs=1e-4)
    assert rmse_v == pytest.approx(rep["v"][0], abs=1e-4)
    assert res.meta["demo"]["rmse_u"] == pytest.approx(rmse_u)
    # the field is really there: 1 % strain over the image gives > 1 px spread
    assert np.ptp(res.u[sel]) > 1.0

    # the images are 8-bit 2-D frames of the requested size
    ref = tifffile.imread(folder / "reference.tif")
    assert ref.shape == (DEMO_SIZE, DEMO_SIZE) and ref.dtype == np.uint8

    # the figure is a real PNG with three panels side by side
    import matplotlib.image as mpimg

    png = mpimg.imread(folder / "displacement.png")
    assert png.ndim == 3 and png.shape[1] > 2 * png.shape[0]


def test_demo_crack_writes_roi(run_cli, tmp_path):
    rc, out, err = run_cli(["demo", "--out", tmp_path, "--size", 96, "--field", "crack",
                         "--step", 12])
    assert rc == 0, err
    roi = tifffile.imread(tmp_path / "roi.tif") > 0
    assert roi.shape == (96, 96) and 0 < (~roi).sum() < 0.1 * roi.size
    res = load_result(tmp_path / "result.npz")
    assert roi[res.y.astype(int), res.x.astype(int)].all()  # no node in the slot
    assert "--roi" in out


# ----------------------------------------------------------------- run
def test_run_pair_reproduces_demo(run_cli, demo, tmp_path):
    folder, _ = demo
    out = tmp_path / "sub" / "pair.npz"
    rc, text, err = run_cli(["run", folder / "reference.tif", folder / "deformed.tif",
                          "--params", folder / "params.json", "-o", out])
    assert rc == 0, err
    assert "frame 1/1" in text and "POI/s" in text
    res = load_result(out)
    ref = load_result(folder / "result.npz")
    np.testing.assert_array_equal(res.valid, ref.valid)
    np.testing.assert_allclose(res.u, ref.u, atol=1e-6)
    np.testing.assert_allclose(res.v, ref.v, atol=1e-6)
    assert res.meta["inputs"]["deformed"].endswith("deformed.tif")


def test_run_stack_writes_one_result_per_frame(run_cli, stack_case, tmp_path):
    path, frames, fields = stack_case
    out = tmp_path / "res.npz"  # a stack: the run folder res/
    rc, text, err = run_cli(["run", path, "-o", out, "--step", 12])
    assert rc == 0, err
    assert "frame 1/2" in text and "frame 2/2" in text
    for k, field in enumerate(fields, start=1):
        res = load_result(tmp_path / "res" / f"frame_{k:05d}.npz")
        assert res.params.step == 12
        # only nodes whose subset moves out of the image may be flagged
        inner = (res.x > 20) & (res.x < 108) & (res.y > 20) & (res.y < 108)
        assert res.valid[inner].all() and res.valid.mean() > 0.8
        assert np.abs(res.u[res.valid] - field.u).max() < 0.02
        assert np.abs(res.v[res.valid] - field.v).max() < 0.02
        assert res.meta["inputs"]["frame"] == k
    assert not (tmp_path / "res.npz").exists()


def test_run_stack_into_folder_with_plot(run_cli, stack_case, tmp_path):
    path, _, _ = stack_case
    rc, _, err = run_cli(["run", path, "-o", tmp_path / "results", "--step", 16, "--plot"])
    assert rc == 0, err
    names = sorted(p.name for p in (tmp_path / "results").iterdir())
    assert names[:-2] == ["fields.zarr", "frame_00000.npz", "frame_00001.npz",
                          "frame_00001.png", "frame_00002.npz", "frame_00002.png"]
    assert names[-2].startswith("roi_") and names[-1] == "sequence.json"


def test_run_folder_in_natural_order(run_cli, stack_case, tmp_path):
    from skimage import io as skio

    _, frames, fields = stack_case
    folder = tmp_path / "images"
    folder.mkdir()
    # frame 0 is img_2, then img_10, then img_100 (not the text order)
    for name, img in zip(("img_2.png", "img_10.png", "img_100.png"), frames):
        skio.imsave(folder / name, img, check_contrast=False)
    rc, _, err = run_cli(["run", folder, "-o", tmp_path / "out", "--step", 16])
    assert rc == 0, err
    res = load_result(tmp_path / "out" / "frame_00002.npz")
    assert res.meta["inputs"]["reference"].endswith("img_2.png")
    assert res.meta["inputs"]["deformed"].endswith("img_100.png")
    assert np.median(res.u[res.valid]) == pytest.approx(fields[1].u, abs=0.02)


def test_params_file_and_overrides(run_cli, demo, tmp_path):
    folder, _ = demo
    params = tmp_path / "p.json"
    params.write_text(json.dumps({"subset": 21, "step": 12, "search": 10}))
    out = tmp_path / "r.npz"
    rc, _, err = run_cli(["run", folder / "reference.tif", folder / "deformed.tif",
                       "--params", params, "--step", 16, "-o", out])
    assert rc == 0, err
    p = load_result(out).params
    assert (p.subset, p.step, p.search) == (21, 16, 10)


def test_method_option_reaches_the_engine(run_cli, demo, tmp_path):
    folder, _ = demo
    out = tmp_path / "r.npz"
    rc, text, err = run_cli(["run", folder / "reference.tif", folder / "deformed.tif",
                          "--method", "aldic", "-o", out])
    assert rc == 0, err
    assert "method aldic" in text
    res = load_result(out)
    assert res.params.method == "aldic"
    field, _ = make_field("strain", (DEMO_SIZE, DEMO_SIZE))
    ut, _ = field.displacement(res.x, res.y)
    assert np.sqrt(np.mean((res.u - ut)[res.valid] ** 2)) < 0.02
    assert "AL-DIC: smoothing length" in text  # the choice is reported


def test_smoothing_options_reach_the_engine(run_cli, demo, tmp_path):
    folder, _ = demo
    out = tmp_path / "r.npz"
    rc, _, err = run_cli(["run", folder / "reference.tif", folder / "deformed.tif",
                       "--method", "aldic", "--smooth", "6.5", "--affine-warp", "-o", out])
    assert rc == 0, err
    res = load_result(out)
    assert res.params.smooth == 6.5 and res.params.second_order_warp is False
    assert res.meta["regularisation"]["smooth_px"] == 6.5
    rc, _, err = run_cli(["run", folder / "reference.tif", folder / "deformed.tif",
                       "--smooth", "lots", "-o", out])
    assert rc != 0 and "--smooth 'lots'" in err


@pytest.mark.parametrize("kind", ["npy", "tif"])
def test_roi_mask_limits_nodes(run_cli, demo, tmp_path, kind):
    folder, _ = demo
    roi = np.zeros((DEMO_SIZE, DEMO_SIZE), bool)
    roi[20:90, 30:110] = True
    if kind == "npy":
        mask = tmp_path / "roi.npy"
        np.save(mask, roi)
    else:
        mask = tmp_path / "roi.tif"
        tifffile.imwrite(mask, roi.astype(np.uint8) * 255, photometric="minisblack")
    out = tmp_path / "r.npz"
    rc, _, err = run_cli(["run", folder / "reference.tif", folder / "deformed.tif",
                       "--roi", mask, "-o", out, "--step", 8])
    assert rc == 0, err
    res = load_result(out)
    assert len(res) > 10
    assert roi[res.y.astype(int), res.x.astype(int)].all()


# ----------------------------------------------------------------- errors
@pytest.fixture
def bad_inputs(demo, stack_case, tmp_path):
    folder, _ = demo
    ref, dfm = folder / "reference.tif", folder / "deformed.tif"
    small = tmp_path / "small.tif"
    tifffile.imwrite(small, np.zeros((64, 80), np.uint8), photometric="minisblack")
    (tmp_path / "unknown.json").write_text('{"subset": 21, "bogus": 1}')
    (tmp_path / "broken.json").write_text('{"subset": 21')
    np.save(tmp_path / "roi_small.npy", np.ones((10, 10), bool))
    np.save(tmp_path / "roi_empty.npy", np.zeros((DEMO_SIZE, DEMO_SIZE), bool))
    (tmp_path / "list.json").write_text("[31, 8]")
    (tmp_path / "text.png").write_text("not an image")
    return dict(ref=ref, dfm=dfm, small=small, stack=stack_case[0], tmp=tmp_path)


@pytest.mark.parametrize("case, expect", [
    ("missing", "no such file"),
    ("mismatch", "small.tif is 64 x 80 pixels, but reference.tif (frame 0) is 128 x 128"),
    ("even_subset", "subset=30"),
    ("unknown_key", "bogus"),
    ("broken_json", "not valid JSON"),
    ("single_frame", "single frame"),
    ("stack_as_pair", "holds 3 frames"),
    ("roi_shape", "ROI mask shape"),
    ("missing_roi", "no such file"),
    ("unreadable", "cannot read image"),
    ("params_list", "JSON object"),
    ("empty_roi", "ROI mask is empty"),
])
def test_bad_input_gives_one_line_error(run_cli, bad_inputs, case, expect):
    b = bad_inputs
    argv = {
        "missing": ["run", b["tmp"] / "nope.tif", b["dfm"]],
        "mismatch": ["run", b["ref"], b["small"]],
        "even_subset": ["run", b["ref"], b["dfm"], "--subset", "30"],
        "unknown_key": ["run", b["ref"], b["dfm"], "--params", b["tmp"] / "unknown.json"],
        "broken_json": ["run", b["ref"], b["dfm"], "--params", b["tmp"] / "broken.json"],
        "single_frame": ["run", b["ref"]],
        "stack_as_pair": ["run", b["stack"], b["dfm"]],
        "roi_shape": ["run", b["ref"], b["dfm"], "--roi", b["tmp"] / "roi_small.npy"],
        "missing_roi": ["run", b["ref"], b["dfm"], "--roi", b["tmp"] / "nope.npy"],
        "unreadable": ["run", b["tmp"] / "text.png", b["dfm"]],
        "params_list": ["run", b["ref"], b["dfm"], "--params", b["tmp"] / "list.json"],
        "empty_roi": ["run", b["ref"], b["dfm"], "--roi", b["tmp"] / "roi_empty.npy"],
    }[case]
    rc, _, err = run_cli(argv + ["-o", b["tmp"] / "out.npz"])
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("napari-aldic: error: ")
    assert expect in lines[0]
    assert "Traceback" not in err
    assert not (b["tmp"] / "out.npz").exists()


def test_usage_errors_and_version(run_cli):
    rc, out, _ = run_cli(["--version"])
    assert rc == 0 and out.strip() == f"napari-aldic {__version__}"
    rc, _, err = run_cli(["run"])
    assert rc == 2 and "required" in err
    rc, _, err = run_cli(["demo", "--field", "nonsense"])
    assert rc == 2 and "invalid choice" in err
    rc, _, err = run_cli(["demo", "--size", "20"])
    assert rc == 2 and err.startswith("napari-aldic: error:")


# ----------------------------------------------------------------- figure
def test_displacement_figure_panels(demo):
    from napari_aldic.engine.viz import displacement_figure

    folder, _ = demo
    res = load_result(folder / "result.npz")
    field, _ = make_field("strain", (DEMO_SIZE, DEMO_SIZE))
    fig = displacement_figure(res, truth=field)
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert "u (px)" in labels and "v (px)" in labels
    assert any(lab.startswith("error") for lab in labels)
    maps = [ax for ax in fig.axes if ax.get_xlabel() == "x (px)"]
    assert len(maps) == 3
    lo, hi = maps[0].images[-1].get_clim()
    u = res.to_grid("u")[np.isfinite(res.to_grid("u"))]
    # u changes sign: symmetric limits, robust (0.5-99.5 %) as in every export
    assert lo == pytest.approx(-hi)
    assert hi == pytest.approx(max(-np.percentile(u, 0.5), np.percentile(u, 99.5)))
    # the axes cover the image in pixel coordinates
    assert maps[0].get_xlim() == (-0.5, DEMO_SIZE - 0.5)
    assert maps[0].get_ylim() == (DEMO_SIZE - 0.5, -0.5)
    # without a truth the third panel shows the correlation quality
    fig = displacement_figure(res)
    assert "ZNCC" in [ax.get_ylabel() for ax in fig.axes]


# ----------------------------------------------------------------- console script
def _console_script():
    exe = Path(sys.executable).parent / "napari-aldic"
    if exe.exists():
        return [str(exe)]
    found = shutil.which("napari-aldic")
    return [found] if found else [sys.executable, "-m", "napari_aldic.cli"]


def test_console_script_runs_in_a_subprocess(demo, tmp_path):
    folder, _ = demo
    cmd = _console_script()
    out = tmp_path / "r.npz"
    proc = subprocess.run(cmd + ["run", str(folder / "reference.tif"),
                                 str(folder / "deformed.tif"), "-o", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "valid" in proc.stdout
    np.testing.assert_allclose(load_result(out).u, load_result(folder / "result.npz").u,
                               atol=1e-6)
    proc = subprocess.run(cmd + ["run", str(tmp_path / "missing.tif"), str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2
    assert proc.stderr.startswith("napari-aldic: error: no such file")
    assert "Traceback" not in proc.stderr


def test_run_stack_incremental_matches_truth(run_cli, stack_case, tmp_path):
    path, frames, fields = stack_case
    out = tmp_path / "inc"
    rc, text, err = run_cli(["run", path, "-o", out, "--step", 12, "--reference", "incremental"])
    assert rc == 0, err
    assert "reference incremental" in text
    res = load_result(out / "frame_00002.npz")
    # results refer to frame 0 even though frame 2 was matched against frame 1
    assert np.abs(res.u[res.valid] - fields[1].u).max() < 0.02
    assert np.abs(res.v[res.valid] - fields[1].v).max() < 0.02


def test_run_several_files_track_against_the_first(run_cli, demo, tmp_path):
    """REF DEF DEF: one image per file, a sequence read by the engine's one reader."""
    folder, _ = demo
    ref, dfm = folder / "reference.tif", folder / "deformed.tif"
    rc, text, err = run_cli(["run", ref, dfm, dfm, "-o", tmp_path / "seq", "--step", 16])
    assert rc == 0, err
    assert "frame 2/2" in text and "2 frames in" in text
    a, b = (load_result(tmp_path / "seq" / f"frame_0000{k}.npz") for k in (1, 2))
    assert a.meta["inputs"]["deformed"] == b.meta["inputs"]["deformed"] == str(dfm)
    assert b.meta["inputs"]["reference"] == str(ref)
    np.testing.assert_allclose(a.u[a.valid & b.valid], b.u[a.valid & b.valid], atol=1e-3)
