"""Strain at the nodes of a :class:`~..core.volresults.VolumeResult`.

Displacement gradient by one of two methods: ``plane_fit`` (least-squares
linear fit of u, v, w over the ``window^3`` trusted lattice neighbours of a
node; the virtual strain gauge is ``(window - 1) step + subset`` voxels) or
``fem`` (the trilinear hexahedra's gradient averaged onto the nodes). Then,
with ``F = I + grad u``: infinitesimal ``(grad u + grad u^T) / 2``,
Green-Lagrange ``(F^T F - I) / 2`` or Euler-Almansi ``(I - F^-T F^-1) / 2``;
principal strains (descending), von Mises equivalent strain
``sqrt(2/3 e':e')`` of the deviator ``e'``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.volresults import VolumeResult
from .grid import VolumeGrid
from .hexmesh import hex_operators, nodal_gradient

__all__ = ["VolumeStrain", "compute_strain_volume", "MEASURES3"]

MEASURES3 = ("infinitesimal", "green_lagrange", "euler_almansi")
COMPONENTS = ("exx", "eyy", "ezz", "exy", "exz", "eyz")


@dataclass
class VolumeStrain:
    """Strain tensor per node (dimensionless; tensor shears)."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    grad: np.ndarray  # (n, 3, 3) displacement gradient, row = (u, v, w), col = d/(x, y, z)
    tensor: np.ndarray  # (n, 3, 3)
    principal: np.ndarray  # (n, 3), descending
    von_mises: np.ndarray
    valid: np.ndarray
    measure: str
    method: str
    window: int

    def component(self, name: str) -> np.ndarray:
        """``exx``, ``eyy``, ``ezz``, ``exy``, ``exz`` or ``eyz``."""
        i, j = {"exx": (0, 0), "eyy": (1, 1), "ezz": (2, 2), "exy": (0, 1), "exz": (0, 2),
                "eyz": (1, 2)}[name]
        return self.tensor[:, i, j]


def _grid(res: VolumeResult) -> VolumeGrid:
    return VolumeGrid(res.grid_xs, res.grid_ys, res.grid_zs, res.grid_ix, res.grid_iy,
                      res.grid_iz)


def _plane_fit(res: VolumeResult, window: int):
    grid = _grid(res)
    r = (window - 1) // 2
    pad = np.pad(grid.index_volume(), r, constant_values=-1)
    offs = [(a, b, c) for a in range(-r, r + 1) for b in range(-r, r + 1) for c in range(-r, r + 1)]
    nb = np.stack([pad[grid.iz + r + a, grid.iy + r + b, grid.ix + r + c] for a, b, c in offs], 1)
    use = nb >= 0
    use[use] = res.valid[nb[use]]
    j = np.maximum(nb, 0)
    X = np.stack([np.ones_like(res.x[j]), res.x[j] - res.x[:, None], res.y[j] - res.y[:, None],
                  res.z[j] - res.z[:, None]], -1) * use[..., None]  # (n, k, 4)
    M = np.einsum("nki,nkj->nij", X, X)
    det_ok = np.linalg.cond(M) < 1e8
    M[~det_ok] = np.eye(4)
    grad = np.empty((len(res), 3, 3))
    for a, name in enumerate(("u", "v", "w")):
        rhs = np.einsum("nki,nk->ni", X, np.where(use, getattr(res, name)[j], 0.0))
        grad[:, a] = np.linalg.solve(M, rhs[..., None])[..., 0][:, 1:]
    return grad, det_ok & res.valid & (use.sum(1) >= 4)


def _fem(res: VolumeResult):
    ops = hex_operators(_grid(res), float(res.params.step))
    grad = np.stack([nodal_gradient(ops, getattr(res, c)) for c in ("u", "v", "w")], 1)
    in_el = np.zeros(len(res), bool)
    in_el[ops.elements.ravel()] = True
    return grad, in_el & res.valid


def strain_tensor(grad: np.ndarray, measure: str) -> np.ndarray:
    """``(n, 3, 3)`` strain of displacement gradients ``grad`` under ``measure``."""
    if measure not in MEASURES3:
        raise ValueError(f"measure={measure!r} must be one of {MEASURES3}")
    eye = np.eye(3)
    if measure == "infinitesimal":
        return 0.5 * (grad + grad.transpose(0, 2, 1))
    F = eye + grad
    if measure == "green_lagrange":
        return 0.5 * (F.transpose(0, 2, 1) @ F - eye)
    Fi = np.linalg.inv(F)
    return 0.5 * (eye - Fi.transpose(0, 2, 1) @ Fi)


def compute_strain_volume(res: VolumeResult, window: int = 3, method: str = "plane_fit",
                          measure: str = "green_lagrange") -> VolumeStrain:
    """Strain at the nodes of a volume result (see the module docstring).

    Raises ``TypeError`` for anything but a VolumeResult and ``ValueError``
    for an unknown method or measure or a window that is even or under 3.
    """
    if not isinstance(res, VolumeResult):
        raise TypeError(f"compute_strain_volume needs a VolumeResult, not {type(res).__name__}")
    if method not in ("plane_fit", "fem"):
        raise ValueError(f"method={method!r} must be 'plane_fit' or 'fem'")
    if window < 3 or window % 2 == 0:
        raise ValueError(f"window={window} must be an odd number of nodes >= 3")
    grad, valid = _plane_fit(res, window) if method == "plane_fit" else _fem(res)
    grad[~valid] = np.nan
    e = strain_tensor(np.nan_to_num(grad), measure)
    e[~valid] = np.nan
    principal = np.full((len(res), 3), np.nan)
    principal[valid] = np.linalg.eigvalsh(e[valid])[:, ::-1]
    dev = e - np.trace(e, axis1=1, axis2=2)[:, None, None] / 3 * np.eye(3)
    vm = np.sqrt(2.0 / 3.0 * (dev ** 2).sum((1, 2)))
    return VolumeStrain(res.x, res.y, res.z, grad, e, principal, vm, valid, measure, method,
                        window)
