"""Statistics of each node over its lattice neighbours.

* :func:`median_flags`: the normalised median test (outlier detection);
* :func:`plane_fit`: least-squares displacement gradients (strain).

Both take a neighbour table ``nbrs`` (n, k) of node indices, -1 for none,
built so that neighbours across a crack or hole are already excluded.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import PARALLEL

__all__ = ["median_flags", "plane_fit"]


@nb.njit(**PARALLEL)
def median_flags(u, v, trusted, nbr, threshold, eps, min_nb, out):
    """Normalised median test, nodes in parallel.

    For each trusted node with at least ``min_nb`` trusted neighbours, and
    for each component: the residual ``|x - median|`` of the node over the
    median absolute fluctuation of its neighbours plus ``eps``; above
    ``threshold`` the node is flagged (J. Westerweel, F. Scarano, "Universal
    outlier detection for PIV data", Exp. Fluids 39, 2005).

    Parameters
    ----------
    u, v : (n,) float64
        Displacements.
    trusted : (n,) bool
        Nodes that may vote and be tested.
    nbr : (n, k) int64
        Neighbour table.
    threshold, eps : float
        Normalised residual limit; noise floor of the fluctuation (pixels).
    min_nb : int
        Nodes with fewer trusted neighbours are not tested.
    out : (n,) bool
        Set True at the outliers (others untouched).
    """
    n, k = nbr.shape
    for i in nb.prange(n):
        if not trusted[i]:
            continue
        a = np.empty(k)
        b = np.empty(k)
        c = 0
        for j in range(k):
            q = nbr[i, j]
            if q >= 0 and trusted[q]:
                a[c] = u[q]
                b[c] = v[q]
                c += 1
        if c < min_nb:
            continue
        for comp in range(2):
            vals = a[:c] if comp == 0 else b[:c]
            x = u[i] if comp == 0 else v[i]
            med = np.median(vals)
            fl = np.median(np.abs(vals - med))
            if abs(x - med) / (fl + eps) > threshold:
                out[i] = True


@nb.njit(**PARALLEL)
def plane_fit(x, y, u, v, use, nbrs, min_pts, out):
    """Least-squares planes ``u = a + b dx + c dy`` (and for ``v``), per node.

    Per node, in parallel: accumulate the normal equations over the node and
    its usable neighbours in coordinates centred on the node, eliminate the
    intercept (covariance form) and solve the 2 x 2 system for the slopes.
    Nodes that are unusable, have fewer than ``min_pts`` points or a
    degenerate point set get NaN.

    Parameters
    ----------
    x, y, u, v : (n,) float64
        Node positions and displacements.
    use : (n,) bool
        Nodes that may be fitted and used.
    nbrs : (n, k) int64
        Neighbour table.
    min_pts : int
        Fewest points (the node included) of a fit.
    out : (n, 4) float64
        Receives ``(du/dx, du/dy, dv/dx, dv/dy)``.
    """
    n, k = nbrs.shape
    for i in nb.prange(n):
        for c in range(4):
            out[i, c] = np.nan
        if not use[i]:
            continue
        # centred normal equations of u = a + b dx + c dy
        s = 1.0
        sx = sy = sxx = sxy = syy = 0.0
        su = sv = sxu = syu = sxv = syv = 0.0
        cnt = 1
        for j in range(k):
            q = nbrs[i, j]
            if q < 0 or not use[q]:
                continue
            dx = x[q] - x[i]
            dy = y[q] - y[i]
            du = u[q] - u[i]
            dv = v[q] - v[i]
            s += 1.0
            sx += dx
            sy += dy
            sxx += dx * dx
            sxy += dx * dy
            syy += dy * dy
            su += du
            sv += dv
            sxu += dx * du
            syu += dy * du
            sxv += dx * dv
            syv += dy * dv
            cnt += 1
        if cnt < min_pts:
            continue
        # eliminate the intercept: covariance form
        cxx = sxx - sx * sx / s
        cxy = sxy - sx * sy / s
        cyy = syy - sy * sy / s
        det = cxx * cyy - cxy * cxy
        if det <= 1e-9 * (cxx + cyy) ** 2 or cxx <= 0 or cyy <= 0:
            continue
        cxu = sxu - sx * su / s
        cyu = syu - sy * su / s
        cxv = sxv - sx * sv / s
        cyv = syv - sy * sv / s
        out[i, 0] = (cyy * cxu - cxy * cyu) / det
        out[i, 1] = (cxx * cyu - cxy * cxu) / det
        out[i, 2] = (cyy * cxv - cxy * cyv) / det
        out[i, 3] = (cxx * cyv - cxy * cxv) / det
