"""``run`` on instrument stacks (units, hyperstacks, zarr) and its reporting (issue 25)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
import zarr

from napari_aldic.engine import load_result, load_run, synthetic

SHAPE = (64, 64)
FAST = ["--subset", "21", "--step", "16"]


@pytest.fixture(scope="module")
def stack() -> np.ndarray:
    ref, d1 = synthetic.speckle_pair(SHAPE, synthetic.Translation(0.4, -0.2), seed=5)
    _, d2 = synthetic.speckle_pair(SHAPE, synthetic.Translation(0.8, -0.4), seed=5)
    return np.stack([ref, d1, d2])


def test_imagej_stack_units_reach_the_results(run_cli, tmp_path, stack):
    path = tmp_path / "ij.tif"
    tifffile.imwrite(path, stack, imagej=True, resolution=(4.0, 4.0),
                     metadata={"axes": "TYX", "unit": "um", "finterval": 2.0})
    rc, out, err = run_cli(["run", path, "-o", tmp_path / "run", *FAST, "-v",
                            "--progress", "json"])
    assert rc == 0, err
    assert "pixel size 0.25 um (ImageJ metadata of ij.tif)" in out
    assert "frame interval 2 s (ImageJ metadata of ij.tif)" in out
    res = load_run(tmp_path / "run")[2]
    assert res.meta["units"]["pixel_size"] == 0.25 and res.meta["units"]["unit"] == "um"
    assert res.meta["units"]["frame_interval"] == 2.0
    assert res.meta["units_source"]["pixel_size"] == "ImageJ metadata of ij.tif"
    # greppable per-frame log lines and JSON progress lines on stderr
    logs = [ln for ln in err.splitlines() if " INFO frame=" in ln]
    assert len(logs) == 2 and "trusted=1.0000" in logs[0] and "compile_s=" in logs[0]
    events = [json.loads(ln) for ln in err.splitlines() if ln.startswith("{")]
    assert events and events[-1]["progress"] == 1.0 and events[-1]["n_frames"] == 2
    assert all(0 <= e["progress"] <= 1 for e in events)


def test_hyperstack_refused_in_one_line_or_channel_chosen(run_cli, tmp_path, stack):
    path = tmp_path / "hyper.tif"
    tifffile.imwrite(path, np.stack([stack, stack[:, :, ::-1]], axis=1), imagej=True,
                     metadata={"axes": "TCYX"})
    rc, _, err = run_cli(["run", path, "-o", tmp_path / "r0", *FAST])
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert "axes TCYX" in err and "--channel" in err
    rc, out, err = run_cli(["run", path, "-o", tmp_path / "r1", *FAST, "--channel", "1",
                            "--quiet"])
    assert rc == 0, err
    assert out == ""  # --quiet: no summaries
    res = load_run(tmp_path / "r1")[1]
    valid = res.valid
    assert valid.mean() > 0.9
    # channel 1 is mirrored in x: the motion is -0.4 px in u
    assert abs(np.median(res.u[valid]) + 0.4) < 0.02


def test_zarr_stack_and_zarr_pair_run(run_cli, tmp_path, stack):
    z = zarr.open_array(tmp_path / "s.zarr", mode="w", shape=stack.shape, dtype=stack.dtype,
                        chunks=(1, *SHAPE))
    z[:] = stack
    rc, _, err = run_cli(["run", tmp_path / "s.zarr", "-o", tmp_path / "zr", *FAST])
    assert rc == 0, err
    assert len(load_run(tmp_path / "zr")) == 3
    for k in (0, 1):
        zarr.open_array(tmp_path / f"{k}.zarr", mode="w", shape=SHAPE,
                        dtype=stack.dtype)[:] = stack[k]
    rc, _, err = run_cli(["run", tmp_path / "0.zarr", tmp_path / "1.zarr", "-o",
                          tmp_path / "p.npz", *FAST])
    assert rc == 0, err
    res = load_result(tmp_path / "p.npz")
    assert abs(np.median(res.u[res.valid]) - 0.4) < 0.02


def test_ome_pair_units_and_source_in_the_result(run_cli, tmp_path, stack):
    for k in (0, 1):
        tifffile.imwrite(tmp_path / f"{k}.ome.tif", stack[k], metadata={
            "axes": "YX", "PhysicalSizeX": 0.65, "PhysicalSizeXUnit": "µm"})
    rc, out, err = run_cli(["run", tmp_path / "0.ome.tif", tmp_path / "1.ome.tif", "-o",
                            tmp_path / "p.npz", *FAST])
    assert rc == 0, err
    res = load_result(tmp_path / "p.npz")
    assert res.meta["units"]["pixel_size"] == 0.65 and res.meta["units"]["unit"] == "um"
    assert res.meta["units_source"] == {"pixel_size": "OME-XML metadata of 0.ome.tif"}
    assert "pixel size 0.65 um (OME-XML metadata of 0.ome.tif)" in out
