"""The AL-DIC stage that follows Local DIC, one implementation for images in
memory (:func:`~.correlate.correlate`) and for pairs correlated block by
block (:func:`~napari_aldic.engine.workflow.tiled.correlate_tiled`).

From the Local result and the pair's :class:`~.reliability.Validity` tests it
chooses the regularisation (the user's smoothing length, or the per-node
lengths of least estimated risk), runs the ADMM iterations of
:mod:`.admm` with the caller's local step (the only part that touches the
images), and gives the result its reasons. The factorised (or AMG
preconditioned) global system can be kept between frames in a
``solver_cache``.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass

import numpy as np

from ..core.params import DICParams
from ..core.reasons import Reason
from .admm import CURVATURE_SMOOTHING, LocalStep, run_admm
from .global_solve import Q4Mesh
from .regularise import choose_smoothing
from .reliability import Validity
from .uncertainty_aldic import ADMMLinearisation, linearise_admm

__all__ = ["ALDICOutcome", "aldic_stage"]


@dataclass
class ALDICOutcome:
    """The AL-DIC result at the nodes, and what ``meta`` records of it."""

    u: np.ndarray  # the global (compatible) field
    v: np.ndarray
    grad: np.ndarray  # (n, 4)
    zncc: np.ndarray
    reason: np.ndarray
    iters: np.ndarray
    history: list
    regularisation: dict
    validity: dict
    #: for the propagated uncertainty of u, v; None where the global system
    #: is solved iteratively (every probe would need its own CG solves)
    admm: ADMMLinearisation | None


def aldic_stage(local_step: LocalStep, mesh: Q4Mesh, validity: Validity, u, v, grad, zncc,
                reason, cut: np.ndarray, params: DICParams, timing: dict, *,
                solver_cache: dict | None = None, on_iteration=None,
                on_factorise=None) -> ALDICOutcome:
    """AL-DIC from a Local result (``u, v, grad, zncc, reason`` per node).

    Parameters
    ----------
    local_step : runs the ADMM local step on the images (:mod:`.admm`).
    mesh : Q4 mesh of the nodes.
    validity : the pair's validity tests, their subset statistics filled in.
    cut : (n,) bool, nodes whose subset the ROI cuts.
    timing : stage times are added to it (``admm_*``, ``smoothing_choice``).
    solver_cache : dict kept between calls (frames of a sequence): the global
        system of the same mesh, trusted nodes and penalties is reused.
    on_iteration : callable(k), called before ADMM iteration k.
    on_factorise : callable(), called as the global system is set up
        (:func:`~.admm.run_admm`).
    """
    # noisy but correct matches are data for the global step too
    trusted = (reason == Reason.OK) | (reason == Reason.UNCERTAIN)
    smooth, second_order, table, noise_var = _regularisation(validity, mesh, u, v, zncc,
                                                             trusted, params)
    key = cached = None
    if solver_cache is not None:
        key = _solver_key(mesh, trusted, params, smooth)
        cached = solver_cache.get(key)
        timing["admm_factor_reused"] = float(cached is not None)
    timing["smoothing_choice"] = timing.get("smoothing_choice", 0.0) + table.pop("seconds")
    state, solver = run_admm(
        local_step, cut, params.half, mesh, u, v, grad, trusted, trusted,
        mu=params.mu, beta=params.beta, step=params.step, smooth=smooth,
        second_order=second_order, noise_var=noise_var, subset=params.subset,
        solver=cached, max_iter=params.admm_max_iter, tol=params.admm_tol,
        on_iteration=on_iteration, on_factorise=on_factorise)
    if solver_cache is not None and cached is None:
        solver_cache.clear()  # keep one system: the mesh of the current frames
        solver_cache[key] = solver
    for k, val in state.timing.items():
        timing["admm_" + k] = timing.get("admm_" + k, 0.0) + val
    zncc_aldic = np.where(np.isfinite(state.zncc), state.zncc, zncc)
    out_reason = _aldic_reasons(validity, state, trusted, reason, zncc_aldic, zncc)
    iters = np.where(out_reason == Reason.OK, state.iterations, 0).astype(np.int32)
    lin = None
    if solver.system.method == "direct":
        lin = linearise_admm(solver, len(state.history), params.mu,
                             trusted & (state.reason == Reason.OK), second_order=second_order,
                             uh=state.uh, vh=state.vh, length=CURVATURE_SMOOTHING * params.half,
                             data=~cut, noise_var=noise_var, smooth=smooth, step=params.step,
                             subset=params.subset)
    return ALDICOutcome(state.uh, state.vh, state.grad, zncc_aldic, out_reason, iters,
                        state.history, _smoothing_record(table, smooth),
                        validity.summary(zncc, out_reason == Reason.OK), lin)


def _solver_key(mesh: Q4Mesh, trusted: np.ndarray, params: DICParams, smooth) -> str:
    """What the global system matrix depends on, hashed (``smooth``: one
    length or per-node lengths)."""
    h = hashlib.sha1()
    for a in (mesh.x, mesh.y, mesh.elements, mesh.hanging, trusted, np.asarray(smooth, float)):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(repr((params.mu, params.beta, params.step)).encode())
    return h.hexdigest()


def _smoothing_record(table: dict, smooth) -> dict:
    """meta["regularisation"]: ``smooth_px`` is the length used, or with
    per-node lengths their mean, with their range and the best single
    length (``smooth_px_global``)."""
    lengths = np.asarray(smooth, float)
    if lengths.ndim == 0:
        return dict(table, smooth_px=float(lengths))
    return dict(table, smooth_px=float(np.mean(lengths)), adaptive=True,
                smooth_px_range=[float(lengths.min()), float(lengths.max())])


def _aldic_reasons(validity: Validity, state, trusted, reason, zncc, zncc_local):
    """Reasons of the AL-DIC result: the local reason of untrusted nodes;
    the last local step's, then the correlation tests of the local result,
    the global-mismatch test and the uncertainty test for the others."""
    reason = np.where(trusted, state.reason, reason).astype(np.int8)
    conv = reason == Reason.OK
    low = conv & ~(zncc >= validity.params.zncc_min)
    poor = conv & ~low & ~(zncc >= validity.zncc_floor(zncc, conv))
    reason[low] = Reason.LOW_CORRELATION
    reason[poor] = Reason.POOR_MATCH
    conv = reason == Reason.OK
    reason[validity.global_mismatch(zncc, zncc_local, conv)] = Reason.GLOBAL_MISMATCH
    reason[validity.uncertain(zncc_local, reason == Reason.OK)] = Reason.UNCERTAIN
    return reason


def _regularisation(validity: Validity, mesh: Q4Mesh, u, v, zncc, trusted: np.ndarray,
                   params: DICParams):
    """The AL-DIC regularisation: ``(smooth_px, second_order, record for meta,
    predicted local noise variances (n, 2) or None when nothing needs them)``;
    the user's smoothing length, or the length (and use of the second-order
    warp) chosen by risk."""
    t = time.perf_counter()
    if params.smooth != "auto" and not params.second_order_warp:
        return float(params.smooth), False, {"mode": "fixed", "second_order_warp": False,
                                             "seconds": 0.0}, None
    var = validity.noise_variance(zncc)
    if params.smooth != "auto":
        return (float(params.smooth), params.second_order_warp,
                {"mode": "fixed", "second_order_warp": params.second_order_warp,
                 "seconds": time.perf_counter() - t}, var)
    curv = CURVATURE_SMOOTHING * params.half if params.second_order_warp else None
    choice = choose_smoothing(mesh, u, v, trusted, var, params.step, params.subset,
                              curv_length=curv)
    ok = trusted & np.isfinite(var).all(axis=1)
    noise = float(np.sqrt(np.mean(var[ok].sum(axis=1)))) if ok.any() else float("nan")
    smooth = choice.smooth_px if choice.node_smooth_px is None else choice.node_smooth_px
    return smooth, choice.second_order, {
        "mode": "auto", "second_order_warp": choice.second_order,
        "smooth_px_global": choice.smooth_px,
        "predicted_local_noise_px": noise,
        "undermatching_bias_px": float(np.sqrt(choice.deconvolution_gain_px2)),
        "risk": choice.table, "seconds": time.perf_counter() - t}, var
