"""Volumes read block by block (issue 28): ``correlate_volume(..., block=N)``.

A volume larger than memory is never loaded whole: every read of the counted
array below is one block's window (under half the volume), and the result is
the whole volume's to the IC-GN tolerance (a few 1e-3 voxel at most).
"""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
import zarr

from napari_aldic.engine import correlate_volume
from napari_aldic.engine.synthetic.volume import VolumeMotion, speckle_volume_pair
from napari_aldic.engine.volume import open_volume

SHAPE = (40, 48, 192)  # long in x: a block's window is under half of it
MOTION = VolumeMotion.make(shift=(1.2, -0.7, 0.5), strain=(0.01, 0.0, -0.005), angle_deg=1.0,
                           centre=(95.5, 23.5, 19.5))
KW = {"subset": 11, "step": 6, "search": 3}


class Counted:
    """An array-like that records the shape of every read."""

    def __init__(self, arr):
        self.arr, self.reads = arr, []
        self.shape, self.dtype, self.ndim = arr.shape, arr.dtype, arr.ndim

    def __getitem__(self, key):
        out = np.asarray(self.arr[key])
        self.reads.append(out.shape)
        return out


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    ref, dfm = speckle_volume_pair(SHAPE, MOTION, seed=2)
    d = tmp_path_factory.mktemp("zarr")
    for name, vol in (("ref", ref), ("def", dfm)):
        z = zarr.create_array(store=str(d / f"{name}.zarr"), shape=vol.shape, dtype="float32",
                              chunks=(16, 16, 16))
        z[:] = vol
    whole = correlate_volume(ref, dfm, **KW)
    return d, ref, dfm, whole


def test_zarr_volumes_are_read_by_blocks_and_give_the_whole_result(pair):
    d, ref, dfm, whole = pair
    a, b = (Counted(open_volume(d / f"{n}.zarr")) for n in ("ref", "def"))
    res = correlate_volume(a, b, **KW, block=24)
    info = res.meta["blocked"]
    assert info["blocks"] >= 8
    total = np.prod(SHAPE)
    for reads in (a.reads, b.reads):
        assert len(reads) == info["blocks"]  # one window per block, never the volume
        assert max(np.prod(s) for s in reads) < 0.5 * total
    assert np.array_equal(res.x, whole.x) and np.array_equal(res.z, whole.z)
    assert np.array_equal(res.valid, whole.valid) and res.valid.mean() > 0.95
    # trusted nodes (an untrusted one holds no measurement); each block starts its
    # nodes from its own guess, and IC-GN stops within tol = 1e-3 of where it would
    # from another start: a few edge nodes of these 11^3 subsets differ by 2e-3
    for c in ("u", "v", "w"):
        diff = (getattr(res, c) - getattr(whole, c))[res.valid]
        assert np.abs(diff).max() < 3e-3 and np.sqrt((diff ** 2).mean()) < 5e-4, c
    truth = MOTION.displacement(res.x, res.y, res.z)
    err = np.stack([res.u, res.v, res.w], 1) - truth
    assert np.sqrt((err[res.valid] ** 2).sum(1).mean()) < 0.005


def test_paths_are_opened_lazily(pair, tmp_path):
    d, ref, dfm, whole = pair
    tifffile.imwrite(tmp_path / "def.tif", dfm, tile=(16, 16))
    vol = open_volume(tmp_path / "def.tif")
    assert vol.shape == SHAPE and not isinstance(vol, np.ndarray)
    np.testing.assert_array_equal(vol[3:9, 10:30, 5:7], dfm[3:9, 10:30, 5:7])
    res = correlate_volume(str(d / "ref.zarr"), tmp_path / "def.tif", **KW, block=32)
    np.testing.assert_allclose(res.u[whole.valid], whole.u[whole.valid], atol=3e-3)


def test_aldvc_by_blocks_gives_the_whole_volume_result(pair):
    d, ref, dfm, _ = pair
    noisy_ref = ref + np.random.default_rng(4).normal(0, 3.0, ref.shape).astype(np.float32)
    noisy_dfm = dfm + np.random.default_rng(5).normal(0, 3.0, dfm.shape).astype(np.float32)
    whole = correlate_volume(noisy_ref, noisy_dfm, **KW, method="aldic")
    b = Counted(noisy_dfm)
    res = correlate_volume(noisy_ref, b, **KW, method="aldic", block=24)
    assert len(b.reads) == res.meta["blocked"]["blocks"] >= 8
    assert max(np.prod(s) for s in b.reads) < 0.5 * np.prod(SHAPE)
    assert np.array_equal(res.x, whole.x) and res.valid.mean() > 0.95
    assert res.meta["regularisation"]["mode"] == "auto" and res.meta["admm_history"]
    both = res.valid & whole.valid
    assert both.mean() > 0.95
    # the ADMM starts from Local fields equal to IC-GN's tolerance (with noise a
    # node's optimum is flat: 0.015 voxel apart at worst from different starts);
    # the global step averages these differences down
    for c in ("u", "v", "w"):
        diff = (getattr(res, c) - getattr(whole, c))[both]
        local = (getattr(res, c + "_local") - getattr(whole, c + "_local"))[both]
        assert np.abs(diff).max() < 6e-3 and np.sqrt((diff**2).mean()) < 5e-4, c
        assert np.sqrt((diff**2).mean()) < 0.7 * np.sqrt((local**2).mean()), c
    truth = MOTION.displacement(res.x, res.y, res.z)
    err = np.stack([res.u, res.v, res.w], 1) - truth
    local = np.stack([res.u_local, res.v_local, res.w_local], 1) - truth
    rms = lambda e: np.sqrt((e[both] ** 2).sum(1).mean())  # noqa: E731
    assert rms(err) < rms(local)


def test_blocks_refuse_mismatched_shapes(pair):
    d, ref, dfm, _ = pair
    with pytest.raises(ValueError, match="one shape"):
        correlate_volume(ref, dfm[:, :, :-1], block=32)
    with pytest.raises(ValueError, match="3-D"):
        np.save(d / "flat.npy", ref[0])
        open_volume(d / "flat.npy")
