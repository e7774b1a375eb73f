"""The display maps behind the result layers (no viewer): the finer grid of a refined
mesh and rigid-body motion, against exact fields."""

from __future__ import annotations

import numpy as np

from napari_aldic.engine.viz import fine_grid, on_fine_grid, rigid_motion


def test_fine_grid_reproduces_an_affine_field_exactly(aldic_result):
    res = aldic_result
    pitch, (x0, y0), shape = fine_grid([res])
    assert pitch == res.params.step / 2 ** round(np.log2(res.params.step / pitch))
    assert pitch < res.params.step  # the quadtree refined around the hole
    field = 0.3 + 0.01 * res.x - 0.02 * res.y  # bilinear elements hold it exactly
    grid = on_fine_grid(res, field, pitch, (x0, y0), shape)
    rows, cols = np.nonzero(np.isfinite(grid))
    assert rows.size > 0.5 * grid.size
    x, y = x0 + cols * pitch, y0 + rows * pitch
    np.testing.assert_allclose(grid[rows, cols], 0.3 + 0.01 * x - 0.02 * y, atol=1e-9)
    # nothing is drawn inside the hole of the ROI (rows/cols 52..76 of the image)
    inside = (x > 56) & (x < 72) & (y > 56) & (y < 72)
    assert not inside.any()


def test_rigid_motion_is_the_rotation_and_translation_part():
    rng = np.random.default_rng(1)
    x, y = rng.uniform(0, 500, 400), rng.uniform(0, 300, 400)
    th, tx, ty = 0.03, -57.0, 12.5
    c, s = np.cos(th), np.sin(th)
    u_rigid = c * (x - 250) - s * (y - 150) + 250 + tx - x
    v_rigid = s * (x - 250) + c * (y - 150) + 150 + ty - y
    strain = 0.004 * (x - x.mean())  # a deformation on top (its rigid part is zero)
    valid = np.ones(x.size, bool)
    valid[:20] = False  # untrusted nodes take no part in the fit
    u = u_rigid + strain
    u[:20] = 1e6
    ur, vr = rigid_motion(x, y, u, v_rigid, valid)
    np.testing.assert_allclose(ur[20:], u_rigid[20:], atol=0.02)
    np.testing.assert_allclose(vr, v_rigid, atol=0.02)
    ur, vr = rigid_motion(x, y, u_rigid, v_rigid)
    np.testing.assert_allclose(u_rigid - ur, 0, atol=1e-9)
    assert rigid_motion(x, y, np.full(x.size, np.nan), v_rigid)[0].max() == 0
