"""The linear noise propagation behind AL-DIC's u_std, v_std
(``dic.uncertainty_aldic``); the Monte-Carlo check is in test_uncertainty_mc.py."""

from __future__ import annotations

import numpy as np
import pytest

from napari_aldic.engine import correlate, synthetic as S
from napari_aldic.engine.dic.global_solve import GlobalSolver, uniform_mesh
from napari_aldic.engine.dic.mesh import make_grid
from napari_aldic.engine.dic.uncertainty_aldic import BatchSolver


def test_batch_solve_is_the_global_solve():
    """Many right-hand sides at once give the solver's own solves."""
    roi = np.ones((120, 140), bool)
    roi[50:70, 60:80] = False  # a hole: untrusted weights, cut elements
    grid = make_grid(roi, 21, 8)
    mesh = uniform_mesh(grid, roi)
    rng = np.random.default_rng(0)
    trusted = rng.random(grid.n) > 0.1
    solver = GlobalSolver(mesh, beta=3.0, mu=1.0, weights=trusted, curvature=50.0,
                          method="direct")
    batch = BatchSolver(solver)
    # an iteratively solved mesh is not propagated (the Local model is reported)
    with pytest.raises(ValueError, match="factorised"):
        BatchSolver(GlobalSolver(mesh, beta=3.0, mu=1.0, weights=trusted, curvature=50.0,
                                 method="amg"))
    n, k = grid.n, 3
    F, W = rng.normal(size=(n, 4, k)), rng.normal(size=(n, 4, k))
    u, v, vu, vv = (rng.normal(size=(n, k)) for _ in range(4))
    uh, vh = batch.solve(F, W, u, v, vu, vv)
    for j in range(k):
        eu, ev = solver.solve(F[:, :, j], W[:, :, j], u[:, j], v[:, j], vu[:, j], vv[:, j])
        # the same factor: equal to rounding
        np.testing.assert_allclose(uh[:, j], eu, rtol=1e-10, atol=1e-12 * np.abs(eu).max())
        np.testing.assert_allclose(vh[:, j], ev, rtol=1e-10, atol=1e-12 * np.abs(ev).max())
        np.testing.assert_allclose(batch.gradients(uh, vh)[:, :, j],
                                   solver.gradients(uh[:, j], vh[:, j]))


def test_aldic_std_is_below_the_subset_std_and_local_is_unchanged():
    """AL-DIC smooths: its u_std is a fraction of the Local result's on the
    same images (0.35-0.6 in the Monte-Carlo runs), everywhere finite."""
    ref, dfm = S.speckle_pair((128, 128), S.Translation(2.3, -1.4), seed=3, noise=4.0)
    loc = correlate(ref, dfm, subset=21, step=8, method="local", max_uncertainty=None)
    al = correlate(ref, dfm, subset=21, step=8, method="aldic", max_uncertainty=None)
    ok = loc.valid & al.valid
    assert ok.sum() > 100
    ratio = np.median(al.u_std[ok] / loc.u_std[ok])
    assert 0.25 < ratio < 0.8, ratio
    assert np.isfinite(al.u_std[ok]).all() and np.isfinite(al.v_std[ok]).all()
