"""Statistics of each node over its lattice neighbours.

* :func:`median_flags`: the normalised median test (outlier detection);
* :func:`plane_fit`: least-squares displacement gradients (strain).

Both take a neighbour table ``nbrs`` (n, k) of node indices, -1 for none,
built so that neighbours across a crack or hole are already excluded.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import INLINE, PARALLEL, SERIAL

__all__ = ["median_flags", "plane_fit"]


@nb.njit(**INLINE)
def _sorted_median(a, c):
    """Median of ``a[:c]``, sorting ``a[:c]`` in place (insertion sort: a
    node has at most a few dozen neighbours); the mean of the two middle
    values for even ``c``, as ``np.median``."""
    for i in range(1, c):
        x = a[i]
        j = i - 1
        while j >= 0 and a[j] > x:
            a[j + 1] = a[j]
            j -= 1
        a[j + 1] = x
    h = c >> 1
    if c % 2 == 0:
        return (a[h - 1] + a[h]) / 2
    return a[h]


@nb.njit(**SERIAL)
def median_flags(first, stop, u, v, trusted, nbr, threshold, eps, min_nb, out):
    """Normalised median test of nodes ``first`` to ``stop`` (serial:
    ``dic.threads.in_threads`` runs ranges side by side).

    For each trusted node with at least ``min_nb`` trusted neighbours, and
    for each component: the residual ``|x - median|`` of the node over the
    median absolute fluctuation of its neighbours plus ``eps``; above
    ``threshold`` the node is flagged (J. Westerweel, F. Scarano, "Universal
    outlier detection for PIV data", Exp. Fluids 39, 2005). The nodes are
    medians sort the few neighbour values in place (the same values as
    ``np.median``).

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
    k = nbr.shape[1]
    a = np.empty(k)
    for i in range(first, stop):
        if not trusted[i]:
            continue
        c = 0
        for j in range(k):
            q = nbr[i, j]
            if q >= 0 and trusted[q]:
                c += 1
        if c < min_nb:
            continue
        for comp in range(2):
            w = u if comp == 0 else v
            c = 0
            for j in range(k):
                q = nbr[i, j]
                if q >= 0 and trusted[q]:
                    a[c] = w[q]
                    c += 1
            med = _sorted_median(a, c)
            for j in range(c):
                a[j] = abs(a[j] - med)
            fl = _sorted_median(a, c)
            if abs(w[i] - med) / (fl + eps) > threshold:
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
