"""AL-DVC's adaptive thin-plate smoothing (engine.volume.smoothing).

The risk estimate is checked on node fields of known truth whose local
errors are correlated exactly as overlapping cubic subsets make them (white
noise box-filtered over the subset, sampled at the nodes), and end to end on
a noisy strained volume, where the smoothed global step must beat the
unsmoothed one.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage as ndi
from scipy import sparse
from scipy.sparse import linalg as spla

from napari_aldic.engine import correlate_volume
from napari_aldic.engine.synthetic.volume import VolumeMotion, speckle_volume_pair
from napari_aldic.engine.volume.grid import make_volume_grid
from napari_aldic.engine.volume.smoothing import choose_volume_smoothing, curvature_rows

SHAPE, SUB, STEP = (120, 120, 120), 21, 8


@pytest.fixture(scope="module")
def grid():
    return make_volume_grid(SHAPE, SUB, STEP)


def _subset_noise(grid, sigma, seed):
    """(n, 3) node errors correlated like overlapping subsets' (std ``sigma``)."""
    rng = np.random.default_rng(seed)
    at = (grid.xyz[:, 2], grid.xyz[:, 1], grid.xyz[:, 0])
    cols = []
    for _ in range(3):
        b = ndi.uniform_filter(rng.normal(size=SHAPE), SUB, mode="wrap")
        cols.append((b * sigma / b.std())[at])
    return np.stack(cols, 1)


def _smoothed(grid, u, lengths):
    K, P = curvature_rows(grid, STEP)
    A = sparse.eye(grid.n) + K.T @ sparse.diags(P @ lengths**4) @ K
    return spla.spsolve(A.tocsc(), u)


def _rms(e):
    return float(np.sqrt((e**2).sum(1).mean()))


def test_thin_plate_rows_ignore_affine_fields_and_have_the_lattice_symbol(grid):
    K, P = curvature_rows(grid, STEP)
    x, y, z = grid.xyz.T.astype(float)
    assert np.abs(K @ (0.3 * x - 0.2 * y + 0.1 * z + 5)).max() < 1e-12
    th = (0.7, 0.3, 1.1)
    wave = np.cos(th[0] * grid.ix + th[1] * grid.iy + th[2] * grid.iz)
    symbol = 16 * sum(np.sin(t / 2) ** 2 for t in th) ** 2 / STEP**4
    # rows need all their nodes: a few are missing at the faces of a 12³ lattice
    assert 0.8 * symbol < np.sum((K @ wave) ** 2) / np.sum(wave**2) < 1.02 * symbol
    np.testing.assert_allclose(np.asarray(P.sum(1)).ravel(), 1.0)


def test_noisy_smooth_field_is_smoothed_and_its_error_halved(grid):
    x, y, z = grid.xyz.T.astype(float)
    truth = np.stack([0.5 * np.sin(x / 40), 0.3 * np.cos(y / 35), 0.2 * np.sin(z / 30)], 1)
    sigma = 0.02
    u_local = truth + _subset_noise(grid, sigma, 1)
    choice = choose_volume_smoothing(grid, u_local, np.ones(grid.n, bool),
                                     np.full(grid.n, 3 * sigma**2), STEP, SUB)
    assert choice.smooth_px > 0.2 * SUB
    fit = _smoothed(grid, u_local, choice.node_smooth_px)
    assert _rms(fit - truth) < 0.55 * _rms(u_local - truth)  # measured 0.51


def test_clean_fine_detail_is_not_smoothed_away(grid):
    x, y, z = grid.xyz.T.astype(float)
    r2 = (x - 60) ** 2 + (y - 60) ** 2 + (z - 60) ** 2
    truth = np.stack([1.5 * np.exp(-r2 / (2 * 8.0**2)), 0 * x, 0 * x], 1)
    sigma = 0.001
    u_local = truth + _subset_noise(grid, sigma, 2)
    choice = choose_volume_smoothing(grid, u_local, np.ones(grid.n, bool),
                                     np.full(grid.n, 3 * sigma**2), STEP, SUB)
    near = r2 < 16**2
    assert choice.node_smooth_px[near].max() <= 0.125 * SUB
    fit = _smoothed(grid, u_local, choice.node_smooth_px)
    assert _rms((fit - truth)[near]) < 1.1 * _rms((u_local - truth)[near])


def test_aldvc_smoothing_beats_the_unsmoothed_global_step_under_noise():
    centre = tuple((s - 1) / 2 for s in (88, 88, 88))
    motion = VolumeMotion.make(strain=(0.02, -0.005, 0.0), centre=centre)
    ref, dfm = speckle_volume_pair((88, 88, 88), motion, noise=4.0, seed=5)
    plain = correlate_volume(ref, dfm, subset=21, step=8, method="aldic", smooth=0.0)
    auto = correlate_volume(ref, dfm, subset=21, step=8, method="aldic")
    both = plain.valid & auto.valid
    assert both.mean() > 0.9

    def rmse(r):
        U = np.stack([r.u, r.v, r.w], 1)[both]
        return _rms(U - motion.displacement(r.x, r.y, r.z)[both])
    assert rmse(auto) < 0.5 * rmse(plain)  # measured 0.39
    reg = auto.meta["regularisation"]
    assert reg["mode"] == "auto" and reg["smooth_px_global"] > 0 and len(reg["risk"]) == 7
    assert plain.meta["regularisation"] == {"mode": "fixed", "smooth_px": 0.0,
                                            "seconds": plain.meta["regularisation"]["seconds"]}


def test_large_lattices_choose_one_length_on_a_central_box(monkeypatch, grid):
    import napari_aldic.engine.volume.smoothing as sm
    x, y, z = grid.xyz.T.astype(float)
    truth = np.stack([0.5 * np.sin(x / 40), 0.3 * np.cos(y / 35), 0.2 * np.sin(z / 30)], 1)
    u_local = truth + _subset_noise(grid, 0.02, 3)
    var = np.full(grid.n, 3 * 0.02**2)
    whole = choose_volume_smoothing(grid, u_local, np.ones(grid.n, bool), var, STEP, SUB)
    rows, sub = sm._central_box(grid, 8**3)
    assert sub.n == rows.size == 8**3 and sub.shape == (8, 8, 8)
    np.testing.assert_array_equal(sub.xyz, grid.xyz[rows])  # same voxels, re-indexed
    monkeypatch.setattr(sm, "ADAPTIVE_MAX_NODES", 1000)
    monkeypatch.setattr(sm, "WINDOW_NODES", 8**3)
    one = choose_volume_smoothing(grid, u_local, np.ones(grid.n, bool), var, STEP, SUB)
    # an 8³ box is more boundary than the 13³ lattice: one rung lower at most
    assert one.node_smooth_px is None and 0.35 * SUB <= one.smooth_px <= whole.smooth_px
