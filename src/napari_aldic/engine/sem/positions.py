"""Measured displacements moved to specimen coordinates, given for each image
the map ``M`` from pixel positions to the specimen: pixel ``x`` shows specimen
``X = x - M(x)`` (``M`` = distortion, plus the image's drift at its scan time).

A node at reference pixel ``x0`` matched at deformed pixel ``x1 = x0 + u``:

    ``U = X1 - X0 = u - M_def(x1) + M_ref(x0)``

and the subset gradients, with ``dX/dx = I - J_M``:
``I + G_true = (I - J_def(x1)) (I + G) (I - J_ref(x0))^-1``. Nothing is
resampled, so no interpolation error is added.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np

from ..core.results import DICResult

__all__ = ["SumMap", "correct_positions"]


class SumMap:
    """The sum of position maps (objects with ``displacement(x, y)`` and
    ``jacobian(x, y)``)."""

    def __init__(self, *maps):
        self.maps = [m for m in maps if m is not None]

    def displacement(self, x, y):
        dx, dy = np.zeros(np.shape(x)), np.zeros(np.shape(x))
        for m in self.maps:
            a, b = m.displacement(x, y)
            dx, dy = dx + a, dy + b
        return dx, dy

    def jacobian(self, x, y):
        out = [np.zeros(np.size(x)) for _ in range(4)]
        for m in self.maps:
            out = [o + np.ravel(j) for o, j in zip(out, m.jacobian(x, y))]
        return tuple(out)


def _eye_minus_j(m, x, y) -> np.ndarray:
    a, b, c, d = m.jacobian(x, y)
    out = np.empty((np.size(x), 2, 2))
    out[:, 0, 0], out[:, 0, 1], out[:, 1, 0], out[:, 1, 1] = 1 - a, -b, -c, 1 - d
    return out


def correct_positions(result: DICResult, ref_map, def_map) -> DICResult:
    """A new result with u, v (also ``u_local``/``v_local``) and the subset
    gradients in specimen coordinates; node positions unchanged."""
    x, y = result.x, result.y
    out = dataclasses.replace(result, meta=copy.deepcopy(result.meta))
    r0x, r0y = ref_map.displacement(x, y)
    for un, vn in (("u", "v"), ("u_local", "v_local")):
        u, v = getattr(result, un), getattr(result, vn)
        if u is None:
            continue
        d1x, d1y = def_map.displacement(x + np.nan_to_num(u), y + np.nan_to_num(v))
        setattr(out, un, u - d1x + r0x)
        setattr(out, vn, v - d1y + r0y)
    n = len(result)
    F = np.empty((n, 2, 2))
    F[:, 0, 0], F[:, 0, 1] = 1 + result.dudx, result.dudy
    F[:, 1, 0], F[:, 1, 1] = result.dvdx, 1 + result.dvdy
    m0 = _eye_minus_j(ref_map, x, y)
    m1 = _eye_minus_j(def_map, x + np.nan_to_num(result.u), y + np.nan_to_num(result.v))
    Ft = m1 @ F @ np.linalg.inv(m0)
    out.dudx, out.dudy = Ft[:, 0, 0] - 1, Ft[:, 0, 1]
    out.dvdx, out.dvdy = Ft[:, 1, 0], Ft[:, 1, 1] - 1
    return out
