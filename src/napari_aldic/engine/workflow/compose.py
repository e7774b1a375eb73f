"""Composition of a sequence's increments: a frame's displacement against
frame 0 from its increment against a later reference (incremental tracking),
``u_total(X) = u_ref(X) + u_inc(X + u_ref(X))`` sampled on the reference's lattice."""

from __future__ import annotations

import numpy as np

from ..core.reasons import Reason
from ..core.results import DICResult

__all__ = ["compose"]


def _sample_on_lattice(res: DICResult, name: str, x: np.ndarray, y: np.ndarray):
    """Bilinear interpolation of a node field at points (NaN where not possible)."""
    from scipy.interpolate import RegularGridInterpolator

    gridv = res.to_grid(name)
    interp = RegularGridInterpolator((res.grid_ys.astype(float), res.grid_xs.astype(float)),
                                     gridv, bounds_error=False, fill_value=np.nan)
    return interp(np.column_stack([y, x]))


def compose(base: DICResult, inc: DICResult) -> DICResult:
    """``u_0k(X) = u_0r(X) + du(X + u_0r(X))``, at the nodes of ``base``.

    ``du`` is interpolated bilinearly on the lattice of ``inc``; where that is
    not possible (next to an untrusted node, or between the lattice's last
    nodes and the image edge, where material moves after frame 0) the nearest
    trusted node is extrapolated with its gradient: within 0.75 steps inside
    the lattice (not across holes), 1.5 steps outside it. Nodes left without
    an increment are flagged with the reason that holds: OUT_OF_IMAGE when
    their subset has left the image, else the nearest increment node's.
    """
    from scipy.spatial import cKDTree

    xd = base.x + base.u
    yd = base.y + base.v
    out = DICResult(**{**base.__dict__})
    names = ("u", "v", "dudx", "dudy", "dvdx", "dvdy", "zncc")
    vals = {n: _sample_on_lattice(inc, n, xd, yd) for n in names}
    miss = base.valid & ~np.all([np.isfinite(v) for v in vals.values()], axis=0)
    inside = ((xd >= inc.grid_xs[0]) & (xd <= inc.grid_xs[-1])
              & (yd >= inc.grid_ys[0]) & (yd <= inc.grid_ys[-1]))
    good = np.nonzero(inc.valid)[0]
    step = float(inc.params.step)
    if miss.any() and good.size:
        # past the lattice edge, but a subset there is inside the image:
        # one extrapolation of the small increment, not of the total motion
        reach = np.where(inside[miss], 0.75, 1.5) * step
        d, j = cKDTree(np.column_stack([inc.x[good], inc.y[good]])).query(
            np.column_stack([xd[miss], yd[miss]]), distance_upper_bound=1.5 * step)
        hit = d <= reach
        src = good[np.where(hit, j, 0)]
        dx = xd[miss] - inc.x[src]
        dy = yd[miss] - inc.y[src]
        fill = {n: getattr(inc, n)[src].astype(float) for n in names}
        fill["u"] = fill["u"] + inc.dudx[src] * dx + inc.dudy[src] * dy
        fill["v"] = fill["v"] + inc.dvdx[src] * dx + inc.dvdy[src] * dy
        idx = np.nonzero(miss)[0][hit]
        for n in names:
            vals[n][idx] = fill[n][hit]
    # F_0k = (I + H_rk(x)) (I + H_0r(X)) - I
    A = np.stack([[1 + vals["dudx"], vals["dudy"]], [vals["dvdx"], 1 + vals["dvdy"]]])
    B = np.stack([[1 + base.dudx, base.dudy], [base.dvdx, 1 + base.dvdy]])
    C = np.einsum("ijn,jkn->ikn", A, B)
    uk, vk = base.u + vals["u"], base.v + vals["v"]
    # as in accumulative tracking, a subset that left frame k is not measured
    gone = _subset_left(inc, base.x, base.y, uk, vk, C - np.eye(2)[:, :, None])
    ok = base.valid & np.all([np.isfinite(v) for v in vals.values()], axis=0) & ~gone
    out.u, out.v = np.where(ok, uk, np.nan), np.where(ok, vk, np.nan)
    out.dudx, out.dudy = C[0, 0] - 1, C[0, 1]
    out.dvdx, out.dvdy = C[1, 0], C[1, 1] - 1
    out.zncc = vals["zncc"]
    out.valid = ok
    out.reason = np.where(ok, Reason.OK, base.reason).astype(np.int8)
    dropped = np.nonzero(base.valid & ~ok)[0]
    if dropped.size:
        _, jn = cKDTree(np.column_stack([inc.x, inc.y])).query(
            np.column_stack([xd[dropped], yd[dropped]]))
        why = inc.reason[jn]
        # a trusted nearest node that could not be used (too far): its
        # material is not covered by the increment's lattice
        why = np.where(why == Reason.OK, Reason.NO_INITIAL_GUESS, why)
        # without an increment, judge by the subset's place in frame k-1
        left = gone[dropped] | _subset_left(inc, xd[dropped], yd[dropped], 0.0, 0.0,
                                             np.zeros((2, 2, 1)))
        out.reason[dropped] = np.where(left, Reason.OUT_OF_IMAGE, why)
    out.meta = {**inc.meta}
    return out


def _subset_left(inc: DICResult, x, y, u, v, grad) -> np.ndarray:
    """Whether a corner of the subset at ``(x, y)``, warped by ``u, v`` and
    the displacement gradient ``grad`` (2, 2, n), leaves ``inc``'s image
    (False where the warp is not known)."""
    rows, cols = inc.image_shape
    h = inc.params.half
    out = np.zeros(np.shape(x), bool)
    with np.errstate(invalid="ignore"):
        for dx in (-h, h):
            for dy in (-h, h):
                xc = x + dx + u + grad[0, 0] * dx + grad[0, 1] * dy
                yc = y + dy + v + grad[1, 0] * dx + grad[1, 1] * dy
                out |= (xc < 0) | (xc > cols - 1) | (yc < 0) | (yc > rows - 1)
    return out
