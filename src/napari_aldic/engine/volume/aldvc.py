"""AL-DVC: ADMM between subset IC-GN and a global trilinear-hexahedral solve.

Algorithm 1 of the pyALDIC paper (Yang & Bhattacharya, Exp. Mech. 59, 2019;
in 3-D Yang et al., Exp. Mech. 60, 2020), with the structure and scaling of
the 2-D :mod:`~..dic.admm` (scaled duals ``W`` on gradients, ``v`` on
displacements), per displacement component ``c``:

1. ``F^{k+1} = G û^k`` (nodal gradients of the global field);
2. local step, per node: the displacement minimising the subset's matching
   cost with the gradient held at ``F^{k+1}`` and the penalty
   ``mu/2 |û^k - u + v^k|^2`` (``mu`` times the subset's mean displacement
   stiffness), on the cost's Gauss-Newton model about the converged Local
   warp (:func:`_model_step`: the Local solve's matrix, no resampling);
3. global step on the hexahedra (2 x 2 x 2 Gauss points, ``β/μ = beta step^2``
   as in 2-D): ``(β/μ GᵀG + I) û = β/μ Gᵀ N (F - W) + (u - v)``;
4. ``W += G û - F``, ``v += û - u``; until ``rms(û^{k+1} - û^k) < admm_tol``.

The global step also carries 2-D's thin-plate term ``Σ κ_r (K û)_r²``
(zero for affine fields), its length ``ℓ`` (``κ = ℓ⁴``) chosen per node by
the risk estimate of :mod:`.smoothing` (``smooth="auto"``) or fixed by the
user (``smooth=ℓ`` voxels; 0: none). Untrusted nodes enter the global step
with a small weight and their neighbours' extrapolated motion, so the system
stays well posed. Not (yet) in 3-D: the second-order warp.
"""

from __future__ import annotations

import time

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from .hexmesh import hex_operators, nodal_gradient
from .local import NodeState, extrapolate
from .smoothing import UNTRUSTED_WEIGHT, choose_volume_smoothing, curvature_rows, spd_solver

__all__ = ["solve_aldvc"]

class _Global:
    """The factorised global matrix of one mesh, weights and thin-plate term."""

    def __init__(self, ops, weight: np.ndarray, ratio: float, curvature=None):
        self.ops = ops
        self.ratio = ratio
        # Gauss-point weights: each point stands for 1/8 of a cell (cell volume 1)
        A = (ratio / 8.0) * (ops.G.T @ ops.G) + sparse.diags(weight)
        if curvature is not None:
            A = A + curvature
        self.weight = weight
        self.solve = spd_solver(A)

    def step(self, target_u: np.ndarray, target_F: np.ndarray) -> np.ndarray:
        """``û`` (n,) of one component from nodal targets (n,) and (n, 3)."""
        ops = self.ops
        gp = np.concatenate([ops.N @ target_F[:, a] for a in range(3)])
        rhs = (self.ratio / 8.0) * (ops.G.T @ gp) + self.weight * target_u
        return self.solve(rhs)


def _fill_untrusted(st: NodeState, good: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Warps with untrusted nodes replaced by their nearest trusted one's
    extrapolated affine map."""
    out = p.copy()
    bad = np.flatnonzero(~good)
    src = np.flatnonzero(good)
    if bad.size and src.size:
        _, j = cKDTree(st.nodes[src]).query(st.nodes[bad])
        out[bad] = extrapolate(p[src[j]], st.nodes[src[j]], st.nodes[bad])
    return out


_T = [0, 4, 8]  # u, v, w in the warp
_F = [1, 2, 3, 5, 6, 7, 9, 10, 11]  # their gradients


def _model_step(st: NodeState, p_loc: np.ndarray, target: np.ndarray, good: np.ndarray,
                mu: float) -> np.ndarray:
    """The local step on each subset's Gauss-Newton model about its Local optimum.

    The matching cost near the converged Local warp ``p_loc`` is
    ``(p - p_loc)ᵀ H (p - p_loc)`` (``H`` the subset's Gauss-Newton matrix, the
    same linearisation ``p o dp^-1 ~ p - dp`` as the sampled step); with the
    gradient held at the global field's and the penalty ``mu`` times the mean
    displacement stiffness, the displacement is
    ``(H_tt + pen) t = H_tt t_loc - H_tF (F - F_loc) + pen q``: no
    resampling of the volume. Untrusted nodes take the target."""
    Htt = st.hrow[:, :, _T]
    HtF = st.hrow[:, :, _F]
    pen = mu * np.trace(Htt, axis1=1, axis2=2) / 3.0
    rhs = (np.einsum("nij,nj->ni", Htt, p_loc[:, _T])
           - np.einsum("nij,nj->ni", HtF, target[:, _F] - p_loc[:, _F])
           + pen[:, None] * target[:, _T])
    out = target.copy()
    A = Htt + pen[:, None, None] * np.eye(3)
    ok = good & np.isfinite(A).all((1, 2)) & (pen > 0)
    out[np.ix_(ok, _T)] = np.linalg.solve(A[ok], rhs[ok][..., None])[..., 0]
    return out


def solve_aldvc(st: NodeState, start: float = 0.5, end: float = 0.95):
    """ADMM from the converged local state ``st`` (updated: its last local
    step). Returns ``(p (n, 12) of the global field, info)``. With
    ``st.report`` set, every ADMM iteration (and batch of local nodes) is a
    progress point, the fraction running from ``start`` to ``end``."""
    pr = st.params
    t0 = time.perf_counter()
    ops = hex_operators(st.grid, float(pr.step))
    if len(ops.elements) == 0:
        return st.p.copy(), {"history": [], "timing": {"admm": 0.0}}
    good = st.good()
    p_loc = st.p.copy()
    # β/μ = beta step^2 (G carries the 1/step): gradients weighed as displacements
    curvature, regularisation = _thin_plate(st, good)
    glob = _Global(ops, np.where(good, 1.0, UNTRUSTED_WEIGHT), pr.beta * pr.step ** 2,
                   curvature)
    p = _fill_untrusted(st, good, st.p)
    comps = (0, 4, 8)
    v = np.zeros((st.grid.n, 3))
    W = np.zeros((st.grid.n, 3, 3))
    u = p[:, comps].copy()
    F = np.stack([p[:, c + 1:c + 4] for c in comps], 1)
    uh = np.stack([glob.step(u[:, a] - v[:, a], F[:, a] - W[:, a]) for a in range(3)], 1)
    history = []
    share = (end - start) / max(pr.admm_max_iter, 1)
    for it in range(pr.admm_max_iter):
        a0 = start + it * share
        if st.report is not None:
            st.report("aldic", a0, f"ADMM iteration {it + 1}")
        Fh = np.stack([nodal_gradient(ops, uh[:, a]) for a in range(3)], 1)
        target = np.zeros_like(st.p)
        for a, c in enumerate(comps):
            target[:, c] = uh[:, a] - v[:, a]
            target[:, c + 1:c + 4] = Fh[:, a]
        st.p[:] = _model_step(st, p_loc, target, good, pr.mu)
        p = _fill_untrusted(st, good, st.p)
        u = p[:, comps]
        uh_new = np.stack([glob.step(u[:, a] - v[:, a], Fh[:, a] - W[:, a])
                           for a in range(3)], 1)
        Fn = np.stack([nodal_gradient(ops, uh_new[:, a]) for a in range(3)], 1)
        W += Fn - Fh
        v += uh_new - u
        change = float(np.sqrt(((uh_new - uh) ** 2).sum(1).mean()))
        history.append({"rms_change": change, "n_good": int(good.sum())})
        uh = uh_new
        if change < pr.admm_tol:
            break
    out = np.zeros_like(st.p)
    Fh = np.stack([nodal_gradient(ops, uh[:, a]) for a in range(3)], 1)
    for a, c in enumerate(comps):
        out[:, c] = uh[:, a]
        out[:, c + 1:c + 4] = Fh[:, a]
    return out, {"history": history, "timing": {"admm": time.perf_counter() - t0},
                 "elements": ops.elements, "regularisation": regularisation}


def _thin_plate(st: NodeState, good: np.ndarray):
    """``(Kᵀ diag(κ) K or None, record for meta)``: the user's smoothing length
    or the per-node lengths of least estimated risk (:mod:`.smoothing`)."""
    pr = st.params
    t = time.perf_counter()
    if pr.smooth != "auto":
        ell = float(pr.smooth)
        record = {"mode": "fixed", "smooth_px": ell}
        nodes = np.full(st.grid.n, ell)
    else:
        var = (st.ustd**2).sum(axis=1)  # NaN where a component has no estimate
        choice = choose_volume_smoothing(st.grid, st.p[:, list(_T)], good, var,
                                         float(pr.step), int(pr.subset))
        nodes = (np.full(st.grid.n, choice.smooth_px) if choice.node_smooth_px is None
                 else choice.node_smooth_px)
        record = {"mode": "auto", "smooth_px_global": choice.smooth_px,
                  "smooth_px_median": float(np.median(nodes)),
                  "predicted_local_noise_px": choice.predicted_local_noise,
                  "risk": choice.table}
    record["seconds"] = time.perf_counter() - t
    if not np.any(nodes > 0):
        return None, record
    K, P = curvature_rows(st.grid, float(pr.step))
    return (K.T @ sparse.diags(P @ nodes**4) @ K), record
