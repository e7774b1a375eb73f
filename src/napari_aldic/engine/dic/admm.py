"""AL-DIC: ADMM iterations between subset IC-GN and the global FE solve.

Algorithm 1 of the pyALDIC paper (after J. Yang, K. Bhattacharya,
"Augmented Lagrangian digital image correlation", Exp. Mech. 59, 2019),
with scaled dual variables ``W`` (gradients) and ``v`` (displacements):

1. ``F^{k+1} = D û^k`` (nodal gradients of the current global field);
2. local step, per node: ``u_i^{k+1} = argmin_u SSD_i(u; F_i^{k+1})
   + mu/2 |û_i^k - u + v_i^k|^2`` (IC-GN on the 2 displacement DOF);
3. global step: ``(β DᵀD + μ I) û^{k+1} = β Dᵀ(F^{k+1} - W^k) + μ (u^{k+1} - v^k)``;
4. ``W += D û^{k+1} - F^{k+1}``, ``v += û^{k+1} - u^{k+1}``;

until ``rms(û^{k+1} - û^k) < tol`` or the iteration cap.

Two additions, both off with ``smooth=0, second_order=False`` (plain
Algorithm 1; see ``docs/method.md`` section 7 for why and what they buy):
the global matrix gains a thin-plate term ``(ℓ⁴/mu) KᵀK`` (zero on affine
fields), and the local step may bend each subset by the smoothed second
derivatives of ``û`` (held fixed like ``F``), which removes the affine
subsets' undermatching bias on curved fields.

Scaling of the penalties (so that one default works for any image contrast,
subset and step): the local penalty is ``mu * tr(H_i) / 2`` with ``H_i`` the
2x2 Gauss-Newton matrix of subset i (``mu`` is dimensionless: 1 means the
penalty is as stiff as the image data of an average direction), and the
global system is divided by ``mu``, leaving ``β/μ = beta * step^2``:
``beta`` is dimensionless too, because the nodal gradient operator scales as
1/step. Larger ``beta`` smooths ``û`` more.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..core.reasons import Reason
from .global_solve import GlobalSolver, Q4Mesh
from .icgn import icgn_solve_translation
from .regularise import curvature_noise_gains, shrink_curvature

# the curvature of the second-order warp is taken from û smoothed over this
# fraction of the subset half-width (keeps the feedback a contraction)
CURVATURE_SMOOTHING = 0.5

__all__ = ["ADMMState", "LocalStep", "run_admm", "image_local_step"]

#: the ADMM local step: ``(start (n, 2), F (n, 4), target (n, 2), mu, active (n,),
#: curvature (n, 6) or None, prior (n, 12) or None, settled (n,) or None) ->
#: (uv (n, 2), zncc, iterations, reason)`` for the ``active`` nodes (see
#: :func:`~.icgn.icgn_solve_translation`; ``prior``: the targets, gradients and
#: curvatures the starts were optimal for; ``settled``: the starts that are
#: sampled optima, whose prediction may be taken unsampled)
LocalStep = Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]


def image_local_step(f, fgx, fgy, g_spline, nodes_x, nodes_y, slot, masks, half: int,
                     max_iter: int, tol: float, lin=None) -> LocalStep:
    """The local step on a pair held in memory: translation-only IC-GN of every
    active node with its gradient fixed (``fgx, fgy``: the steepest-descent
    gradients; ``lin``: the exact ones, :func:`~.icgn.icgn_solve`; ``slot,
    masks``: the subsets cut by the ROI)."""

    def step(start, F, target, mu, active, curvature, prior=None, settled=None):
        return icgn_solve_translation(f, fgx, fgy, g_spline, nodes_x, nodes_y, start, F,
                                      target, mu, active, slot, masks, half, max_iter, tol,
                                      curvature=curvature, lin=lin, prior=prior,
                                      settled=settled)

    return step


@dataclass
class ADMMState:
    """Outcome of the ADMM iterations."""

    uh: np.ndarray  # global (compatible) displacement along x, per node
    vh: np.ndarray
    u: np.ndarray  # last local displacement
    v: np.ndarray
    grad: np.ndarray  # (n, 4) gradients D û of the final global field
    zncc: np.ndarray
    reason: np.ndarray
    iterations: np.ndarray  # local IC-GN iterations of the last ADMM pass
    history: list = field(default_factory=list)  # per ADMM iteration dict
    timing: dict = field(default_factory=dict)


def run_admm(local_step: LocalStep, cut: np.ndarray, half: int, mesh: Q4Mesh,
             u0: np.ndarray, v0: np.ndarray, grad0: np.ndarray, trusted: np.ndarray,
             usable: np.ndarray, *, mu: float, beta: float, step: float, max_iter: int,
             tol: float, smooth: float | np.ndarray = 0.0, second_order: bool = False,
             noise_var: np.ndarray | None = None, subset: int | None = None,
             solver: GlobalSolver | None = None, solver_method: str = "auto",
             on_iteration=None, on_factorise=None) -> tuple[ADMMState, GlobalSolver]:
    """Run AL-DIC ADMM from a Local DIC result.

    Parameters
    ----------
    local_step : the local step on the images (:func:`image_local_step`, or block by block).
    cut : (n,) bool, nodes whose subset the ROI cuts (their warp stays affine).
    half : subset half-width (pixels).
    u0, v0, grad0 : local DIC displacements and (n, 4) gradients.
    trusted : nodes whose local result is reliable (data weight 1).
    usable : nodes whose subset can be correlated at all (mask component OK).
    mu, beta : dimensionless penalties (see module docstring).
    smooth : thin-plate smoothing length of the global step, pixels (0: none);
        or an (n,) array of per-node lengths (adaptive smoothing).
    second_order : bend each subset by the global field's second derivatives.
    noise_var : (n, 2) predicted local displacement variances; with
        ``subset``, used to shrink noisy curvature estimates (see
        :func:`~napari_aldic.engine.dic.regularise.shrink_curvature`).
    solver : a :class:`GlobalSolver` to reuse (same mesh and weights).
    solver_method : linear solver of the global step (see
        :func:`~napari_aldic.engine.dic.linear_solvers.solver_method`).
    on_iteration : callable(k), optional; called before ADMM iteration k
        (a progress / cancellation point).
    on_factorise : callable(), optional; called as the global system is set up
        (its factorisation leaves a core idle: the caller starts work there).
    """
    timing = {"global_factorise": 0.0, "global_solve": 0.0, "local": 0.0}
    solver = _global_solver(solver, mesh, trusted, beta * step**2, smooth, mu,
                            solver_method, timing, on_factorise)
    W, vu, vv, uh, vh = _start(solver, grad0, u0, v0, timing)
    n = u0.size
    u, v = u0.copy(), v0.copy()
    zncc = np.full(n, np.nan)
    reason = np.where(usable, Reason.OK, Reason.SMALL_COMPONENT).astype(np.int8)
    iters = np.zeros(n, np.int32)
    history, active = [], usable.copy()
    gains = None
    if second_order and noise_var is not None and subset is not None:
        gains = _noise_gains(smooth, CURVATURE_SMOOTHING * half, step, subset)
    grad = solver.gradients(uh, vh)
    # the targets, gradients and curvatures the local displacements are optimal
    # for: the Local DIC result is the data term's own optimum (no penalty: its
    # own target) with its own gradient and an affine warp; trusted Local
    # results converged there (settled), the others are starts only
    prior = np.column_stack([u, v, grad0, np.zeros((n, 6))])
    settled = trusted.copy()
    for k in range(max_iter):
        if on_iteration is not None:
            on_iteration(k + 1)
        F = solver.gradients(uh, vh)
        # nodes outside every element keep their own local gradient
        F[~solver.covered] = grad0[~solver.covered]
        target = np.column_stack([uh + vu, vh + vv])
        start = np.column_stack([u, v])
        t = time.perf_counter()
        curv = (_warp_curvature(solver, uh, vh, half, cut, gains, noise_var)
                if second_order else None)
        uv, zncc_k, iters, reason_k = local_step(start, F, target, mu, active, curv, prior,
                                                 settled)
        timing["local"] += time.perf_counter() - t
        ok = active & (reason_k == Reason.OK)
        u, v, zncc, prior = _accept(ok, uv, zncc_k, target, F, curv, u, v, zncc, prior)
        settled |= ok
        reason = np.where(active, reason_k, reason).astype(np.int8)
        uh_new, vh_new, G = _global_step(solver, F, W, u, v, vu, vv, timing)
        history.append(_progress(k, uh, vh, uh_new, vh_new, u, v, trusted, iters, ok))
        uh, vh, grad = uh_new, vh_new, G
        if history[-1]["uhat_change_px"] < tol:
            break
    grad = grad.copy()
    grad[~solver.covered] = grad0[~solver.covered]  # no element: local gradient
    return ADMMState(uh, vh, u, v, grad, zncc, reason, iters, history, timing), solver


def _accept(ok, uv, zncc_k, target, F, curv, u, v, zncc, prior) -> tuple:
    """``(u, v, zncc, prior)`` after a local step: where it succeeded (``ok``)
    its displacements, the ZNCC it measured (a prediction taken unsampled
    measured none, NaN: the last one measured stays, at first Local's) and
    the target, gradient and curvature they are optimal for; a failed step
    keeps the previous values (no new information)."""
    u = np.where(ok, uv[:, 0], u)
    v = np.where(ok, uv[:, 1], v)
    zncc = np.where(ok & np.isnan(zncc_k), zncc, zncc_k)
    prior = np.where(ok[:, None], np.column_stack(
        [target, F, np.zeros((ok.size, 6)) if curv is None else curv]), prior)
    return u, v, zncc, prior


def _global_solver(solver: GlobalSolver | None, mesh: Q4Mesh, trusted, beta_step2: float,
                   smooth, mu: float, method: str, timing: dict,
                   on_factorise=None) -> GlobalSolver:
    """The global step's solver (``solver`` when reused: a sequence's next
    frame), its factor's copy for the u_std propagation started meanwhile;
    ``on_factorise()`` is called first."""
    if on_factorise is not None:
        on_factorise()
    t = time.perf_counter()
    if solver is None:
        solver = GlobalSolver(mesh, beta=beta_step2, mu=1.0, weights=trusted,
                              curvature=np.asarray(smooth, float)**4 / mu, method=method)
    timing["global_factorise"] = time.perf_counter() - t
    solver.system.triangular_ahead()
    return solver


def _start(solver: GlobalSolver, grad0, u0, v0, timing: dict) -> tuple:
    """``(W, vu, vv, uh, vh)``: the scaled multipliers of the constraints
    ``D û = F`` and ``u = û`` (zero) and the initial global field, the
    compatible projection of the local result."""
    n = u0.size
    W, vu, vv = np.zeros((n, 4)), np.zeros(n), np.zeros(n)
    t = time.perf_counter()
    uh, vh = solver.solve(grad0, W, u0, v0, vu, vv)
    timing["global_solve"] += time.perf_counter() - t
    return W, vu, vv, uh, vh


def _noise_gains(smooth, curv_length: float, step: float, subset: int):
    """:func:`curvature_noise_gains` of one length, or per node (arrays) of
    per-node lengths (each distinct length computed once)."""
    smooth = np.asarray(smooth, float)
    if smooth.ndim == 0:
        return curvature_noise_gains(float(smooth), curv_length, step, subset)
    lengths, inverse = np.unique(smooth, return_inverse=True)
    g = np.array([curvature_noise_gains(float(ell), curv_length, step, subset)
                  for ell in lengths])
    return g[inverse, 0], g[inverse, 1]


def _global_step(solver: GlobalSolver, F, W, u, v, vu, vv, timing: dict):
    """Global step and dual update: solve for ``û``, then ``W += D û - F``
    and ``v += û - u`` (``W``, ``vu``, ``vv`` in place). Returns
    ``(uh, vh, D û)``."""
    t = time.perf_counter()
    uh, vh = solver.solve(F, W, u, v, vu, vv)
    timing["global_solve"] += time.perf_counter() - t
    G = solver.gradients(uh, vh)
    W += G - F
    vu += uh - u
    vv += vh - v
    return uh, vh, G


def _warp_curvature(solver: GlobalSolver, uh, vh, half: int, cut, gains, noise_var):
    """Second derivatives of ``û`` for the second-order warp of the local step:
    smoothed over ``CURVATURE_SMOOTHING * half``, shrunk where noisy (when
    ``gains`` are known), zero on subsets cut by the ROI edge."""
    # cut subsets (next to holes, cracks, the outline) are often poorly
    # matched: the curvature smoother interpolates over them instead
    curv = solver.second_gradients(uh, vh, CURVATURE_SMOOTHING * half, data=~cut)
    if gains is not None:
        curv = shrink_curvature(curv, noise_var, gains)
    # subsets cut by a hole/crack/outline keep the affine warp: next to
    # a discontinuity the smoothed curvature is one-sided and unreliable
    curv[cut] = 0.0
    return curv


def _progress(k: int, uh, vh, uh_new, vh_new, u, v, trusted, iters, ok) -> dict:
    """History entry of ADMM iteration ``k``: the change of ``û`` (the
    stopping criterion), the primal residual ``û - u`` on trusted nodes, the
    mean local IC-GN iterations and how many nodes took the linear prediction
    unsampled (0 iterations)."""
    change = float(np.sqrt(np.mean((uh_new - uh) ** 2 + (vh_new - vh) ** 2)))
    gap = ((uh_new - u) ** 2 + (vh_new - v) ** 2)[trusted]
    primal = float(np.sqrt(np.mean(gap))) if gap.size else 0.0
    return {"iteration": k + 1, "uhat_change_px": change, "primal_residual_px": primal,
            "local_iterations_mean": float(iters[ok].mean()) if ok.any() else 0.0,
            "local_predicted": int(np.count_nonzero(ok & (iters == 0)))}
