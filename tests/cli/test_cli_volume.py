"""``napari-aldic run --volume`` (issue 28), 3-D strain and the volume exports."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from napari_aldic.engine import (
    DICResult,
    VolumeResult,
    compute_strain_volume,
    correlate_volume,
    export_volume,
    load_result,
)
from napari_aldic.engine.synthetic.volume import VolumeMotion, speckle_volume_pair

SHAPE = (40, 40, 40)
MOTION = VolumeMotion.make(strain=(0.02, -0.01, 0.005), angle_deg=4.0, centre=(19.5,) * 3)


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    ref, dfm = speckle_volume_pair(SHAPE, MOTION, seed=7)
    d = tmp_path_factory.mktemp("vol")
    tifffile.imwrite(d / "ref.tif", ref)
    tifffile.imwrite(d / "def.tif", dfm)
    return d, ref, dfm


def test_cli_volume_gives_the_api_result(run_cli, pair, tmp_path):
    d, ref, dfm = pair
    rc, out, err = run_cli(["run", d / "ref.tif", d / "def.tif", "--volume", "--subset", "21",
                            "--step", "8", "-o", tmp_path / "out.npz"])
    assert rc == 0, err
    res = load_result(tmp_path / "out.npz")
    api = correlate_volume(ref, dfm, subset=21, step=8)
    assert isinstance(res, VolumeResult)
    for k in ("x", "y", "z", "u", "v", "w", "valid", "reason"):
        assert np.array_equal(getattr(res, k), getattr(api, k)), k


@pytest.mark.parametrize("method", ["local", "aldic"])
def test_cli_block_reads_tiled_volumes_and_gives_the_api_blocked_result(run_cli, pair,
                                                                          tmp_path, method):
    d, ref, dfm = pair
    for name, vol in (("ref", ref), ("def", dfm)):
        tifffile.imwrite(tmp_path / f"{name}.tif", vol, tile=(16, 16))
    rc, out, err = run_cli(["run", tmp_path / "ref.tif", tmp_path / "def.tif", "--volume",
                            "--block", "16", "--method", method, "-o", tmp_path / "out.npz"])
    assert rc == 0, err
    res = load_result(tmp_path / "out.npz")
    api = correlate_volume(ref, dfm, subset=21, step=8, method=method, block=16)
    assert res.meta["blocked"]["blocks"] == api.meta["blocked"]["blocks"] == 8
    for k in ("x", "y", "z", "u", "v", "w", "valid", "reason"):
        assert np.array_equal(getattr(res, k), getattr(api, k)), k


def test_cli_block_needs_volume_and_a_block_of_a_node_spacing(run_cli, pair):
    d, _, _ = pair
    rc, out, err = run_cli(["run", d / "ref.tif", d / "def.tif", "--block", "32"])
    assert rc != 0 and "--volume" in err
    rc, out, err = run_cli(["run", d / "ref.tif", d / "def.tif", "--volume", "--block", "4"])
    assert rc != 0 and "--block 4" in err and "8" in err


def test_cli_without_volume_keeps_3d_tiff_as_2d_frames(run_cli, tmp_path):
    ref, _ = speckle_volume_pair((3, 64, 64), VolumeMotion.make(shift=(0.5, 0, 0)), seed=1)
    tifffile.imwrite(tmp_path / "stack.tif", ref, photometric="minisblack")
    rc, out, err = run_cli(["run", tmp_path / "stack.tif", "--subset", "21", "-o",
                            tmp_path / "run"])
    assert rc == 0, err
    frames = sorted((tmp_path / "run").glob("frame_*.npz"))
    assert len(frames) == 3 and isinstance(load_result(frames[-1]), DICResult)  # 2-D frames


def test_cli_volume_refuses_a_2d_file_naming_it(run_cli, tmp_path):
    tifffile.imwrite(tmp_path / "flat.tif", np.zeros((30, 30), np.float32))
    rc, out, err = run_cli(["run", tmp_path / "flat.tif", tmp_path / "flat.tif", "--volume"])
    assert rc != 0 and "flat.tif" in err


@pytest.mark.parametrize("method", ["plane_fit", "fem"])
@pytest.mark.parametrize("measure", ["infinitesimal", "green_lagrange", "euler_almansi"])
def test_strain_of_uniform_strain_and_rotation(pair, method, measure):
    _, ref, dfm = pair
    res = _result(ref, dfm)
    s = compute_strain_volume(res, method=method, measure=measure)
    F = MOTION.A
    G = F - np.eye(3)
    Fi = np.linalg.inv(F)
    want = {"infinitesimal": 0.5 * (G + G.T), "green_lagrange": 0.5 * (F.T @ F - np.eye(3)),
            "euler_almansi": 0.5 * (np.eye(3) - Fi.T @ Fi)}[measure]
    assert s.valid.mean() > 0.9
    # 4 degrees make the infinitesimal shear differ from the finite measures by ~1e-3
    np.testing.assert_allclose(np.median(s.tensor[s.valid], 0), want, atol=3e-4)
    np.testing.assert_allclose(np.median(s.principal[s.valid], 0),
                               np.sort(np.linalg.eigvalsh(want))[::-1], atol=3e-4)


_CACHE: dict = {}


def _result(ref, dfm):
    if "res" not in _CACHE:
        _CACHE["res"] = correlate_volume(ref, dfm, subset=21, step=8)
    return _CACHE["res"]


def test_exports_mat_vtu_csv(pair, tmp_path):
    _, ref, dfm = pair
    res = _result(ref, dfm)
    s = compute_strain_volume(res)
    from scipy.io import loadmat
    m = loadmat(export_volume(res, tmp_path / "r.mat", s))
    np.testing.assert_array_equal(m["u"].ravel(), res.u)
    text = export_volume(res, tmp_path / "r.vtu", s).read_text()
    cells = np.prod(np.array(res.grid_shape) - 1)
    assert f'NumberOfPoints="{len(res)}"' in text and f'NumberOfCells="{cells}"' in text
    rows = np.loadtxt(export_volume(res, tmp_path / "r.csv", s), delimiter=",", skiprows=1)
    assert rows.shape[0] == len(res)
    np.testing.assert_allclose(rows[:, 3], res.u, rtol=1e-9)
    with pytest.raises(ValueError, match="xlsx"):
        export_volume(res, tmp_path / "r.xlsx")
