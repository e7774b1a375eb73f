"""``napari-aldic run`` on a stack: the run folder of ``track``, resumed, and
never mixed with another analysis (issue 11, section 2)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import tifffile

from napari_aldic.engine import load_run, track

STEP = ["--subset", 21, "--step", 24]




def _files(folder):
    """Every file under ``folder`` (the field store ``fields.zarr`` is a folder)."""
    return {p.relative_to(folder).as_posix(): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def tif(export_stack, tmp_path):
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, export_stack[:3], photometric="minisblack")
    return path


def test_run_writes_the_track_folder_and_resumes_it(run_cli, tif, tmp_path, export_stack):
    out = tmp_path / "run"
    rc, text, err = run_cli(["run", tif, "-o", out, *STEP])
    assert rc == 0, err
    doc = json.loads((out / "sequence.json").read_text())
    assert doc["format"] == "napari-aldic-run" and doc["format_version"] == 2
    assert doc["frames"] == [0, 1, 2] and doc["stack"]["files"][0]["name"] == "stack.tif"
    first = load_run(out)
    ref = track(export_stack[:3], subset=21, step=24)
    np.testing.assert_allclose(first[2].u, ref[2].u, atol=1e-9)
    (out / "frame_00002.npz").unlink()  # as if the run had been killed before frame 2
    kept = _files(out)
    rc, text, err = run_cli(["run", tif, "-o", out, *STEP])
    assert rc == 0, err
    assert "1 frames in" in text and "1 finished frame(s) resumed" in text
    now = _files(out)
    assert now["frame_00001.npz"] == kept["frame_00001.npz"]  # loaded, not rewritten
    # recomputed from its own FFT guess (frame 1 came from disk): same field to 1e-3 px
    np.testing.assert_allclose(load_run(out)[2].u, first[2].u, atol=1e-3)


def test_run_refuses_a_folder_of_another_analysis(run_cli, tif, tmp_path, export_stack):
    other = tmp_path / "other"  # an unrelated 4-frame analysis
    track(export_stack, subset=21, step=12, out_dir=other)
    before = _files(other)
    rc, text, err = run_cli(["run", tif, "-o", other, *STEP])
    assert rc == 2 and "Traceback" not in err
    assert err.startswith(f"napari-aldic: error: {other} holds results of a different analysis")
    assert "the parameters changed (step 12 -> 24)" in err and err.count("\n") == 1
    assert _files(other) == before  # not one frame overwritten
    old = tmp_path / "old_cli"  # the previous CLI's output: frame###.npz, no manifest
    old.mkdir()
    (old / "frame001.npz").write_bytes(b"previous result")
    rc, _, err = run_cli(["run", tif, "-o", old, *STEP])
    assert rc == 2 and "frame001.npz) but no sequence.json" in err


def test_run_refuses_a_changed_roi_and_a_busy_folder(run_cli, tif, tmp_path):
    out = tmp_path / "run"
    roi = np.ones((128, 128), bool)
    roi[:, :40] = False
    np.save(tmp_path / "roi.npy", roi)
    assert run_cli(["run", tif, "-o", out, *STEP])[0] == 0
    rc, _, err = run_cli(["run", tif, "-o", out, "--roi", tmp_path / "roi.npy", *STEP])
    assert rc == 2 and "the ROI changed (16,384 px" in err
    holder = ("import sys, time\nfrom napari_aldic.engine.core.files import folder_lock\n"
              "with folder_lock(sys.argv[1]):\n    print('locked', flush=True)\n"
              "    time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", holder, str(out)], stdout=subprocess.PIPE,
                            text=True)
    try:
        assert proc.stdout.readline().strip() == "locked"
        rc, _, err = run_cli(["run", tif, "-o", out, *STEP])
        assert rc == 2 and f"{out} is in use by another napari-aldic run (process " \
            f"{proc.pid}" in err
    finally:
        proc.kill()
        proc.wait()
