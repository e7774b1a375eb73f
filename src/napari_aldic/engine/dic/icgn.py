"""Inverse-compositional Gauss-Newton (IC-GN) subset matching.

Affine (first-order) shape function with parameters
``p = (u, du/dx, du/dy, v, dv/dx, dv/dy)``: the subset pixel at offset
``(dx, dy)`` from the node maps to
``(x0 + dx + u + ux*dx + uy*dy, y0 + dy + v + vx*dx + vy*dy)``.
The matching criterion is the zero-normalised sum of squared differences
(ZNSSD), robust to affine grey-level changes. The inverse-compositional
update linearises the *reference* subset, so the Gauss-Newton Hessian is
built once per node and every iteration only samples the deformed image
(B-spline, precomputed coefficients) and accumulates nine sums in a single
pass.

References: S. Baker, I. Matthews, "Lucas-Kanade 20 years on", IJCV 56, 2004;
B. Pan, K. Li, W. Tong, "Fast, robust and accurate DIC calculation without
redundant computations", Exp. Mech. 53, 2013.

The second-order (quadratic) shape function adds the six second derivatives
``(uxx, uxy, uyy, vxx, vxy, vyy)`` (``shape="quadratic"``, kernel
:mod:`~napari_aldic.engine.kernels.icgn_quadratic`): the subset may bend,
which keeps the amplitude of displacements that vary over a subset width
(H. Lu, P. D. Cary, Exp. Mech. 40, 2000).

Steepest-descent images and linearisation. Each step solves
``M dp = -Σ J r`` with ``M = Σ J eᵀ``: ``e`` is the steepest-descent image
built from the exact spline gradient of the reference (the true
linearisation of the warped residual) and ``J`` the one the residual is
projected on. With ``J = e`` this is plain Gauss-Newton; with ``J`` from a
smoothed reference (less noise) it is an instrumental-variable
Gauss-Newton step: the iteration still converges like Newton's (the model
of how the residual moves is exact), while it solves ``Σ J r = 0``, whose
noise is lower. Smoothing ``J`` and keeping the symmetric ``Σ J Jᵀ``
instead leaves the step too long by the ratio of the unsmoothed to the
smoothed gradient energy: on fine speckle that ratio passes 2 and the
iteration no longer converges (issue 22: 83 % of a real coupon at the
iteration cap).

The Numba kernels are in :mod:`napari_aldic.engine.kernels.icgn` and
:mod:`~napari_aldic.engine.kernels.gauss_newton`; the functions here prepare
their inputs and outputs.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..core.reasons import Reason
from ..kernels import gauss_newton as status
from ..kernels.icgn import icgn_affine, icgn_translation
from ..kernels.icgn_quadratic import NPAR, icgn_quadratic
from .subsets import check_masks
from .threads import in_threads

__all__ = ["icgn_solve", "icgn_solve_translation", "SHAPE_FUNCTIONS", "convergence_record",
           "warn_iteration_cap", "CAP_WARN_FRACTION"]

#: the subset shape functions ``icgn_solve`` knows
SHAPE_FUNCTIONS = ("affine", "quadratic")

# the kernels write these status codes as plain integers
if (status.OK, status.NOT_CONVERGED, status.OUT_OF_IMAGE, status.NO_TEXTURE,
        status.DIVERGED) != (
        Reason.OK, Reason.NOT_CONVERGED, Reason.OUT_OF_IMAGE, Reason.NO_TEXTURE,
        Reason.DIVERGED):
    raise ImportError("kernels.gauss_newton status codes disagree with core.reasons.Reason")

_NOT_CONVERGED = int(Reason.NOT_CONVERGED)

#: warn when more than this fraction of a run's solvable nodes ends at the
#: iteration cap: a few such nodes are noise, many mean the solver (or its
#: settings: ``max_iter``, ``tol``) does not suit the images
CAP_WARN_FRACTION = 0.02


def convergence_record(reason, iterations, usable, max_iter: int) -> dict:
    """How IC-GN converged over a run, for ``res.meta["convergence"]``.

    Parameters
    ----------
    reason, iterations : (n,) arrays
        Final reason codes and IC-GN iterations per node.
    usable : (n,) bool
        Nodes whose subset could be solved at all (not cut away by the ROI).
    max_iter : int
        The iteration cap.

    Returns
    -------
    dict
        ``max_iter``; ``median_iterations`` and ``p95_iterations`` of the
        trusted nodes (None without any); ``predicted``: trusted nodes with 0
        iterations (AL-DIC's last local step took their linear prediction,
        ``method.md`` 7); ``at_cap``: nodes flagged ``NOT_CONVERGED``;
        ``fraction_at_cap``: their share of the usable ones.
    """
    reason = np.asarray(reason)
    it = np.asarray(iterations)[reason == Reason.OK]
    predicted = int(np.count_nonzero(it == 0))
    at_cap = int(np.count_nonzero(reason == Reason.NOT_CONVERGED))
    n_usable = int(np.count_nonzero(usable))
    return {"max_iter": int(max_iter),
            "median_iterations": float(np.median(it)) if it.size else None,
            "p95_iterations": float(np.percentile(it, 95)) if it.size else None,
            "predicted": predicted,
            "at_cap": at_cap, "fraction_at_cap": at_cap / n_usable if n_usable else 0.0}


def warn_iteration_cap(record: dict, stacklevel: int = 3) -> None:
    """A ``RuntimeWarning`` when more than :data:`CAP_WARN_FRACTION` of the
    nodes of ``record`` (:func:`convergence_record`) hit the iteration cap."""
    if record["fraction_at_cap"] > CAP_WARN_FRACTION:
        warnings.warn(
            f"{record['at_cap']} nodes ({100 * record['fraction_at_cap']:.1f} % of the "
            f"solvable ones) hit the IC-GN iteration cap (max_iter={record['max_iter']}) "
            "and are flagged 'not converged': check the images (blur, saturation, very "
            "large deformation within a subset) or raise max_iter / tol",
            RuntimeWarning, stacklevel=stacklevel)


def icgn_solve(f, fgx, fgy, spline, nodes_x, nodes_y, p_init, active, slot, masks,
               half, max_iter=40, tol=1e-3, out=None, stats=None, shape="affine", lin=None,
               static=None):
    """Run IC-GN at the ``active`` nodes.

    Parameters
    ----------
    f, fgx, fgy : (H, W) float32
        Reference image and the gradients of the steepest-descent images
        (the spline gradients, or smoothed ones:
        :func:`~.interpolation.steepest_descent_gradients`).
    spline : SplineImage
        Deformed-image B-spline coefficients.
    nodes_x, nodes_y : (n,) int64
        Node pixel coordinates.
    p_init : (n, 6) float64
        Initial parameters ``(u, ux, uy, v, vx, vy)``.
    active : (n,) bool
        Nodes to solve; the others are left untouched in ``out``.
    slot, masks : see :class:`~napari_aldic.engine.dic.subsets.SubsetMasks`.
    half : int
        Subset half-width in pixels.
    out : tuple or None
        ``(p, zncc, iters, reason)`` arrays to update in place.
    stats : (n, 5) float64 or None
        Receives, at the active nodes, the reference subset statistics
        ``(m, var_f, hxx, hxy, hyy)`` (see
        :class:`~napari_aldic.engine.dic.reliability.SubsetStats`).
    shape : {"affine", "quadratic"}
        Subset shape function. ``"quadratic"`` starts every node with zero
        second derivatives and returns only the affine part in ``p`` (the
        displacement and its gradient at the node).
    lin : (egx, egy) or None
        The reference's exact spline gradients, which linearise the warp
        (None: ``fgx, fgy`` themselves). With smoothed ``fgx, fgy`` each step
        is an instrumental-variable Gauss-Newton step (module docstring).
    static : (g, var_img, min_motion, out[, min_fraction]) or None
        Affine warps only: the deformed image (float32), the noise variance of
        one image and the least motion (px) at which the converged active
        nodes get the zero-motion evidence ``(S / D, z)`` of
        :func:`~napari_aldic.engine.kernels.static.zero_motion_evidence` in
        ``out`` (n, 2) (NaN at the other active nodes; :mod:`.static`);
        ``z`` only where ``S / D > min_fraction`` (default 0), else NaN.

    Returns
    -------
    p, zncc, iters, reason
    """
    n = nodes_x.size
    check_masks(slot, masks, half, n)
    if out is None:
        out = (np.array(p_init, dtype=np.float64, copy=True), np.full(n, np.nan),
               np.zeros(n, np.int32), np.full(n, _NOT_CONVERGED, np.int8))
    p, zn, it, rs = out
    if stats is None:
        stats = np.empty((n, 5))
    egx, egy = (fgx, fgy) if lin is None else lin
    if shape == "affine":
        g, var_img, min_motion, s_out, min_fraction = \
            (f, 0.0, 0.0, np.empty((0, 2)), 0.0) if static is None else (*static, 0.0)[:5]
        in_threads(icgn_affine, -(-n // status.CHUNK), f, fgx, fgy, egx, egy, spline.coef,
                   spline.order, nodes_x, nodes_y,
                   np.ascontiguousarray(p_init, dtype=np.float64), active, slot, masks,
                   int(half), int(max_iter), float(tol), p, zn, it, rs, stats, g,
                   (float(var_img), float(min_motion), float(min_fraction)), s_out)
    elif shape == "quadratic":
        p12 = np.zeros((n, NPAR))
        p12[:, :6] = p_init
        q = np.zeros((n, NPAR))
        q[:, :6] = p
        in_threads(icgn_quadratic, -(-n // status.CHUNK), f, fgx, fgy, egx, egy, spline.coef,
                   spline.order, nodes_x, nodes_y, p12, active, slot, masks, int(half),
                   int(max_iter), float(tol), q, zn, it, rs, stats)
        p[active] = q[active, :6]
    else:
        raise ValueError(f"shape={shape!r} must be one of {SHAPE_FUNCTIONS}")
    return p, zn, it, rs


#: a settled node takes the linear prediction of its local-step optimum without
#: sampling when no sample moved more than this (px) from where the subset was
#: optimal: the prediction's error is then second order in that move (against
#: a sampled step, 99th percentile 0.4-5e-4 px on the 1024² pair and the OHT
#: coupon, up to 1.5e-3 px in the crack's passes, largest 5e-3 px there;
#: benchmarks/RESULTS.md, "Eighteenth session")
PREDICTION_REACH = 0.05
#: ... and when that move, as a misfit of the subset (px, see
#: ``reliability.Validity.misfit``), is at most half the global-mismatch
#: test's tolerance (``reliability.GLOBAL_TOLERANCE``): the ZNCC a sample
#: would measure could not fail that test
PREDICTION_MISFIT = 0.1


def icgn_solve_translation(f, fgx, fgy, spline, nodes_x, nodes_y, uv_init, grad, target,
                           mu, active, slot, masks, half, max_iter=40, tol=1e-3,
                           curvature=None, lin=None, prior=None, settled=None):
    """AL-DIC local step: IC-GN on the displacement only, with the gradient fixed.

    Minimises, per node, ``SSD(u; F fixed) + mu' / 2 |u - target|^2`` where
    ``mu' = mu * tr(H) / 2`` scales the dimensionless ``mu`` by the subset's
    Gauss-Newton stiffness (H: 2x2 Hessian of the data term), so one ``mu``
    suits every image contrast and subset size.

    Parameters
    ----------
    uv_init : (n, 2) starting displacements.
    grad : (n, 4) fixed gradients (du/dx, du/dy, dv/dx, dv/dy).
    target : (n, 2) penalty targets ``û + v`` (scaled multiplier included).
    mu : float, dimensionless penalty weight.
    curvature : (n, 6) or None
        Fixed second derivatives ``(uxx, uxy, uyy, vxx, vxy, vyy)`` (1/px)
        added to the warp as ``0.5 dXᵀ ∇∇u dX``; None keeps the warp affine.
    lin : (egx, egy) or None
        Exact reference gradients (as :func:`icgn_solve`).
    prior : (n, 12) or None
        The penalty targets, gradients and second derivatives the starts were
        optimal for (the previous ADMM iteration's; for a Local DIC start the
        start itself, its own gradient and zero curvature): the iteration
        then starts from the linear prediction of the new optimum (one
        sampled step fewer on most nodes; the converged result moves by
        less than ``tol``).
    settled : (n,) bool or None
        Nodes whose start is a sampled optimum for ``prior``: where the
        prediction moves no sample more than ``PREDICTION_REACH`` (and
        ``PREDICTION_MISFIT`` as a misfit), it is taken without sampling the
        deformed image (0 iterations, ZNCC NaN: not measured again). None:
        every node is sampled.

    Returns
    -------
    uv, zncc, iters, reason
    """
    curv = (np.zeros((0, 6)) if curvature is None
            else np.ascontiguousarray(curvature, np.float64))
    prior = np.zeros((0, 12)) if prior is None else np.ascontiguousarray(prior, np.float64)
    n = nodes_x.size
    if settled is None:
        settled, reach = np.zeros(n, bool), (0.0, 0.0)
    else:
        settled, reach = np.ascontiguousarray(settled, bool), (PREDICTION_REACH,
                                                                PREDICTION_MISFIT)
    check_masks(slot, masks, half, n)
    uv = np.array(uv_init, dtype=np.float64, copy=True)
    zn = np.full(n, np.nan)
    it = np.zeros(n, np.int32)
    rs = np.full(n, _NOT_CONVERGED, np.int8)
    egx, egy = (fgx, fgy) if lin is None else lin
    in_threads(
        icgn_translation, -(-n // status.CHUNK), f, fgx, fgy, egx, egy, spline.coef,
        spline.order, nodes_x, nodes_y,
        np.ascontiguousarray(uv_init, np.float64), np.ascontiguousarray(grad, np.float64), curv,
        np.ascontiguousarray(target, np.float64), prior, settled, reach, float(mu), active,
        slot, masks, int(half), int(max_iter), float(tol), uv, zn, it, rs)
    return uv, zn, it, rs
