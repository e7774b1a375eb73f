"""A sequence of volumes: every volume against volume 0, or against the previous one.

``reference="accumulative"`` correlates volume ``k`` with volume 0.
``reference="incremental"`` correlates volume ``k`` with volume ``k - 1`` and
composes the increment onto the previous total at the material points, in
the reference configuration (Lagrangian): a node at ``X`` is at
``x = X + U_{k-1}(X)`` in volume ``k - 1``, so ``U_k(X) = U_{k-1}(X) +
du(x)`` and ``F_k = (I + grad du(x)) F_{k-1}``, with the increment ``du``
and its gradient interpolated trilinearly on the increment's node lattice
(exact for affine motion). A node is trusted when it was at ``k - 1`` and
all eight increment nodes around ``x`` are.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator, Mapping

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from ..core.reasons import Reason
from ..core.volresults import VolumeResult
from .correlate import correlate_volume

__all__ = ["track_volumes", "compose_increment"]

_GRAD = ("dudx", "dudy", "dudz", "dvdx", "dvdy", "dvdz", "dwdx", "dwdy", "dwdz")
REFERENCES = ("accumulative", "incremental")


def _sample(inc: VolumeResult, name: str, pts: np.ndarray) -> np.ndarray:
    """Field ``name`` of ``inc`` (NaN at untrusted nodes) at ``pts`` (z, y, x),
    trilinear (nearest along an axis of one node), extrapolated linearly
    beyond the lattice."""
    axes = (inc.grid_zs.astype(float), inc.grid_ys.astype(float), inc.grid_xs.astype(float))
    grid = inc.to_grid(name)
    method = "linear" if min(grid.shape) >= 2 else "nearest"  # one node along an axis
    return RegularGridInterpolator(axes, grid, method=method, bounds_error=False,
                                   fill_value=None)(pts)


def compose_increment(prev: VolumeResult, inc: VolumeResult) -> VolumeResult:
    """The total displacement of ``prev``'s nodes after the increment ``inc``
    (measured from the volume ``prev`` ends in); a new result, ``prev``
    unchanged (see the module docstring)."""
    pts = np.stack([prev.z + prev.w, prev.y + prev.v, prev.x + prev.u], 1)
    out = copy.copy(prev)
    out.meta = copy.deepcopy(prev.meta)
    du = np.stack([_sample(inc, c, pts) for c in ("u", "v", "w")], 1)
    G = np.stack([_sample(inc, k, pts) for k in _GRAD], 1).reshape(-1, 3, 3)
    F = (np.eye(3) + G) @ (np.eye(3) + prev.F)
    out.u, out.v, out.w = (np.asarray(getattr(prev, c), float) + du[:, i]
                           for i, c in enumerate("uvw"))
    for k, (i, j) in zip(_GRAD, [(i, j) for i in range(3) for j in range(3)]):
        setattr(out, k, F[:, i, j] - (1.0 if i == j else 0.0))
    ok = np.isfinite(du).all(1) & np.isfinite(G).all((1, 2))
    out.valid = prev.valid & ok
    lost = prev.valid & ~ok
    out.reason = np.where(lost, _lost_reason(inc), prev.reason).astype(np.int8)
    for s in ("u_std", "v_std", "w_std"):
        a, b = getattr(prev, s), getattr(inc, s)
        if a is not None and b is not None:
            setattr(out, s, np.sqrt(np.asarray(a) ** 2 + _sample(inc, s, pts) ** 2))
    out.zncc = _sample(inc, "zncc", pts)
    out.iterations = prev.iterations + np.nan_to_num(_sample(inc, "iterations", pts)).astype(
        prev.iterations.dtype)
    out.u_local = out.v_local = out.w_local = None
    out.meta["n_valid"] = out.n_valid
    return out


def _lost_reason(inc: VolumeResult) -> int:
    """The commonest reason among the increment's untrusted nodes."""
    bad = inc.reason[~inc.valid]
    return int(np.bincount(bad).argmax()) if bad.size else int(Reason.OUTLIER)


def _frames(volumes):
    if isinstance(volumes, np.ndarray) and volumes.ndim == 4:
        return [volumes[k] for k in range(volumes.shape[0])]
    return list(volumes)


def track_volumes(volumes, roi=None, reference: str = "accumulative", *, params=None,
                  done: Mapping[int, VolumeResult] | None = None, progress=None,
                  cancel=None, **options) -> Iterator[tuple[int, VolumeResult]]:
    """Correlate a sequence of volumes; yields ``(k, result)`` for ``k = 1, 2 ...``.

    Parameters
    ----------
    volumes : sequence of (nz, ny, nx) arrays, or a (t, nz, ny, nx) array
        Volume 0 is the reference configuration.
    roi : (nz, ny, nx) bool or None
        Material in volume 0 (used for every pair).
    reference : {"accumulative", "incremental"}
        Every volume against volume 0, or against the previous one composed
        onto the previous total (see the module docstring).
    params, options, progress, cancel
        As :func:`~.correlate.correlate_volume` (``progress`` gets each
        pair's events).
    done : {k: VolumeResult}, optional
        Frames already measured (a resumed run): yielded as they are and,
        incremental, the base of the next frame.
    """
    if reference not in REFERENCES:
        raise ValueError(f"reference={reference!r} must be one of {REFERENCES}")
    vols = _frames(volumes)
    done = dict(done or {})
    prev = None
    for k in range(1, len(vols)):
        if k in done:
            prev = done[k]
            yield k, prev
            continue
        base = 0 if reference == "accumulative" or prev is None else k - 1
        res = correlate_volume(vols[base], vols[k], roi, params=params, progress=progress,
                               cancel=cancel, **options)
        if base:
            res = compose_increment(prev, res)
        res.meta["inputs"] = {"frame": k, "reference": reference, "against": base}
        prev = res
        yield k, res
