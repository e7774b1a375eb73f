"""Field maps for display (NumPy/SciPy only): the deformed configuration, the
finer grid of a refined (quadtree) mesh, and rigid-body motion.

A result's node values live on the node lattice of the reference image. To
draw them where the material is in the deformed frame, every lattice point
``x`` takes the value of the material point ``X`` with ``X + u(X) = x``
(:func:`to_deformed`). Quadtree nodes between lattice points are drawn on a
grid as fine as the smallest element (:func:`fine_grid`, :func:`on_fine_grid`),
and :func:`rigid_motion` gives the rotation and translation part of a field so
that a display can subtract it.
"""

from __future__ import annotations

import numpy as np

from ..io import result_cells

__all__ = ["to_deformed", "fine_grid", "on_fine_grid", "rigid_motion"]


def _fill_nearest(a: np.ndarray) -> np.ndarray:
    """``a`` with every non-finite entry replaced by its nearest finite one
    (all zeros when nothing is finite)."""
    from scipy import ndimage

    bad = ~np.isfinite(a)
    if not bad.any() or bad.all():
        return np.where(bad, 0.0, a)
    idx = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
    return a[tuple(idx)]


def to_deformed(grids: list[np.ndarray], u: np.ndarray, v: np.ndarray, step: float,
                iterations: int = 12) -> list[np.ndarray]:
    """Lattice fields moved to the deformed configuration.

    Parameters
    ----------
    grids : list of (rows, cols) arrays
        Node values on the lattice of the reference image (NaN where there
        is no trusted value).
    u, v : (rows, cols) arrays
        Displacement in pixels on the same lattice.
    step : float
        Lattice spacing in pixels.
    iterations : int
        Fixed-point iterations.

    Returns
    -------
    list of (rows, cols) arrays
        The value shown at lattice point ``x`` is that of the material point
        ``X`` with ``X + u(X) = x``, found by the fixed-point iteration
        ``X <- x - u(X)`` with bilinear interpolation; points that no trusted
        material reaches are NaN.
    """
    from scipy import ndimage

    ok = np.isfinite(u) & np.isfinite(v)
    if not ok.any():
        return [np.full_like(g, np.nan) for g in grids]
    uf, vf = _fill_nearest(u) / step, _fill_nearest(v) / step  # lattice units
    rr, cc = np.mgrid[0:u.shape[0], 0:u.shape[1]].astype(float)
    R, C = rr.copy(), cc.copy()
    for _ in range(iterations):
        du = ndimage.map_coordinates(uf, [R, C], order=1, mode="nearest")
        dv = ndimage.map_coordinates(vf, [R, C], order=1, mode="nearest")
        R, C = rr - dv, cc - du
    inside = ndimage.map_coordinates(ok.astype(float), [R, C], order=0, mode="constant",
                                     cval=0.0) > 0.5
    out = []
    for g in grids:
        val = ndimage.map_coordinates(_fill_nearest(g), [R, C], order=1, mode="nearest")
        val[~inside | ~np.isfinite(ndimage.map_coordinates(
            np.where(np.isfinite(g), 0.0, np.nan), [R, C], order=0, mode="nearest"))] = np.nan
        out.append(val)
    return out


def fine_grid(results) -> tuple[float, tuple[float, float], tuple[int, int]]:
    """The grid that shows every node of ``results`` (DICResults of one lattice):
    ``(pitch, (x0, y0), (rows, cols))`` in image pixels.

    The pitch is the width of the smallest element (the step divided by a power
    of two on a quadtree mesh; the step itself without refinement); the grid
    starts at the first lattice node and spans the lattice.
    """
    base = results[0]
    step = float(base.grid_xs[1] - base.grid_xs[0]) if base.grid_xs.size > 1 else \
        float(base.params.step)
    pitch = step
    for res in results:
        cells = result_cells(res)
        if len(cells):
            width = float(np.min(res.x[cells[:, 1]] - res.x[cells[:, 0]]))
            if width > 0:
                pitch = min(pitch, step / 2.0 ** round(np.log2(step / width)))
    x0, y0 = float(base.grid_xs[0]), float(base.grid_ys[0])
    rows = int(round((float(base.grid_ys[-1]) - y0) / pitch)) + 1
    cols = int(round((float(base.grid_xs[-1]) - x0) / pitch)) + 1
    return pitch, (x0, y0), (rows, cols)


def on_fine_grid(res, values: np.ndarray, pitch: float, origin, shape) -> np.ndarray:
    """Node ``values`` of ``res`` on the grid of :func:`fine_grid`.

    Inside every element the value is the bilinear (Q4) interpolation of its
    corners, the field the finite-element mesh represents (hanging nodes lie on
    their edge's interpolation, so neighbouring elements agree); a grid point on
    a node takes the node's value. NaN where no element or node is (holes, ROI
    outside) and in elements with a NaN corner.
    """
    values = np.asarray(values, float)
    out = np.full(shape, np.nan)
    x0, y0 = origin
    cells = result_cells(res)
    if len(cells):
        width = res.x[cells[:, 1]] - res.x[cells[:, 0]]
        n_of = np.rint(width / pitch).astype(np.int64)
        for n in np.unique(n_of):
            if n < 1:
                continue
            c = cells[n_of == n]
            t = np.arange(n + 1) / n
            s, r = np.meshgrid(t, t)  # s along x (columns), r along y (rows)
            v = values[c][:, :, None, None]
            val = ((1 - s) * (1 - r) * v[:, 0] + s * (1 - r) * v[:, 1] + s * r * v[:, 2]
                   + (1 - s) * r * v[:, 3])
            col0 = np.rint((res.x[c[:, 0]] - x0) / pitch).astype(np.int64)
            row0 = np.rint((res.y[c[:, 0]] - y0) / pitch).astype(np.int64)
            rows = row0[:, None, None] + np.arange(n + 1)[None, :, None]
            cols = col0[:, None, None] + np.arange(n + 1)[None, None, :]
            rows, cols = np.broadcast_to(rows, val.shape), np.broadcast_to(cols, val.shape)
            ok = (rows >= 0) & (rows < shape[0]) & (cols >= 0) & (cols < shape[1])
            out[rows[ok], cols[ok]] = val[ok]
    col = np.rint((np.asarray(res.x, float) - x0) / pitch).astype(np.int64)
    row = np.rint((np.asarray(res.y, float) - y0) / pitch).astype(np.int64)
    ok = (row >= 0) & (row < shape[0]) & (col >= 0) & (col < shape[1])
    out[row[ok], col[ok]] = values[ok]
    return out


def rigid_motion(x, y, u, v, valid=None) -> tuple[np.ndarray, np.ndarray]:
    """The rigid-body part of a displacement field at every node: the rotation
    and translation that best map the trusted nodes (least squares, the 2-D
    Procrustes/Kabsch solution), as displacements ``(ur, vr)``.

    ``u - ur``, ``v - vr`` is the field without rigid-body motion (a pure
    rotation and translation gives zero). Untrusted or non-finite nodes do not
    take part in the fit; with none left the result is zero.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    u, v = np.asarray(u, float), np.asarray(v, float)
    ok = np.isfinite(u) & np.isfinite(v) & np.isfinite(x) & np.isfinite(y)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    if not ok.any():
        return np.zeros_like(x), np.zeros_like(y)
    px, py = x[ok], y[ok]
    qx, qy = px + u[ok], py + v[ok]
    mx, my, nx, ny = px.mean(), py.mean(), qx.mean(), qy.mean()
    ax, ay, bx, by = px - mx, py - my, qx - nx, qy - ny
    theta = np.arctan2(np.sum(ax * by - ay * bx), np.sum(ax * bx + ay * by))
    c, s = np.cos(theta), np.sin(theta)
    dx, dy = x - mx, y - my
    return c * dx - s * dy + nx - x, s * dx + c * dy + ny - y
