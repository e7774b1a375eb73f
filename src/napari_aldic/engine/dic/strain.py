"""Strain from a displacement result.

Displacement gradients ``H = grad u`` (reference configuration) come from

* ``method="plane_fit"``: a least-squares plane ``u = a + b dx + c dy`` (and
  the same for v) fitted, at every node, to the trusted nodes of a
  ``window x window`` node neighbourhood (a radius of ``(window-1)/2`` node
  spacings on quadtree meshes) that the centre node can see inside the ROI;
  neighbours across a crack or hole never enter the fit. The virtual strain
  gauge is ``VSG = (window - 1) * step + subset`` pixels.
* ``method="fem"``: nodal gradients of the bilinear (Q4) interpolation of the
  displacements on the result's mesh (the mean of the element gradients at the
  node; VSG = ``2 * step + subset``).

With ``F = I + H`` the strain measures are

* infinitesimal: ``eps = (H + H^T) / 2``;
* Green-Lagrange: ``E = (F^T F - I) / 2``;
* Euler-Almansi: ``e = (I - F^-T F^-1) / 2`` (a spatial measure, reported at
  the material points of the nodes).

Derived quantities, for the in-plane tensor ``[[exx, exy], [exy, eyy]]``
(``exy`` is the tensor shear, half the engineering shear):

* principal strains ``e1, e2 = (exx + eyy)/2 +- sqrt(((exx - eyy)/2)^2 + exy^2)``;
* maximum in-plane shear (tensor) ``(e1 - e2) / 2``;
* equivalent (von Mises) strain ``sqrt(2/3 (exx^2 + eyy^2 + ezz^2 + 2 exy^2))``
  with ``ezz = -(exx + eyy)`` (plastic incompressibility);
* rotation ``atan2(F21 - F12, F11 + F22)`` in radians: the rotation of the
  polar decomposition ``F = R U`` (exact in 2-D), positive from +x towards
  +y (clockwise on screen, since y points down).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..core.params import StrainParams
from ..core.reasons import DICError
from ..core.results import DICResult
from ..kernels.lattice import plane_fit

__all__ = ["StrainResult", "compute_strain", "strain_measures"]

MEASURES = ("infinitesimal", "green_lagrange", "euler_almansi")
METHODS = ("plane_fit", "fem")


@dataclass
class StrainResult:
    """Strain at the nodes of a :class:`DICResult` (dimensionless)."""

    x: np.ndarray
    y: np.ndarray
    exx: np.ndarray
    eyy: np.ndarray
    exy: np.ndarray  # tensor shear
    e1: np.ndarray
    e2: np.ndarray
    max_shear: np.ndarray
    von_mises: np.ndarray
    rotation: np.ndarray  # radians
    dudx: np.ndarray
    dudy: np.ndarray
    dvdx: np.ndarray
    dvdy: np.ndarray
    valid: np.ndarray
    measure: str
    method: str
    window: int
    vsg: float  # virtual strain gauge, pixels


def strain_measures(dudx, dudy, dvdx, dvdy, measure: str = "green_lagrange"):
    """``(exx, eyy, exy)`` of the displacement gradient under ``measure``."""
    if measure not in MEASURES:
        raise ValueError(f"measure={measure!r} must be one of {MEASURES}")
    if measure == "infinitesimal":
        return dudx, dvdy, 0.5 * (dudy + dvdx)
    if measure == "green_lagrange":
        exx = dudx + 0.5 * (dudx**2 + dvdx**2)
        eyy = dvdy + 0.5 * (dudy**2 + dvdy**2)
        exy = 0.5 * (dudy + dvdx + dudx * dudy + dvdx * dvdy)
        return exx, eyy, exy
    # Euler-Almansi: e = (I - B^-1) / 2 with B^-1 = F^-T F^-1
    F11, F12, F21, F22 = 1 + dudx, dudy, dvdx, 1 + dvdy
    det = F11 * F22 - F12 * F21
    i11, i12, i21, i22 = F22 / det, -F12 / det, -F21 / det, F11 / det  # F^-1
    b11 = i11 * i11 + i21 * i21
    b22 = i12 * i12 + i22 * i22
    b12 = i11 * i12 + i21 * i22
    return 0.5 * (1 - b11), 0.5 * (1 - b22), -0.5 * b12


def _grid_of(result: DICResult):
    from .mesh import NodeGrid

    return NodeGrid(result.x.astype(np.int64), result.y.astype(np.int64), result.grid_ix,
                    result.grid_iy, result.grid_xs, result.grid_ys)


#: largest neighbour table (bytes) a plane-fit window may need
_MAX_TABLE_BYTES = 4 << 30


def _check_arguments(result, window, method: str, measure: str) -> None:
    """Refuse wrong types and windows too large to mean anything, at once."""
    if not isinstance(result, DICResult):
        hint = {"SequenceResult": "; pass one frame, e.g. seq[k]",
                "StrainResult": " (that is already a strain)"}.get(type(result).__name__, "")
        if isinstance(result, (str, os.PathLike)):
            hint = "; read the file first with load_result(path)"
        raise TypeError(f"compute_strain needs a DICResult (the result of one frame), not "
                        f"{type(result).__name__}{hint}")
    if method not in METHODS:
        raise ValueError(f"method={method!r} must be one of {METHODS}")
    if measure not in MEASURES:
        raise ValueError(f"measure={measure!r} must be one of {MEASURES}")
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 3 \
            or window % 2 == 0:
        raise DICError("not_odd", f"window={window!r} must be an odd number of nodes >= 3 "
                       "(e.g. 5)", name="window", value=window)
    rows, cols = result.grid_shape
    widest = 2 * max(rows, cols, 2) - 1  # from a corner node, every node is in the window
    if window > widest:
        raise ValueError(f"window={window} nodes is wider than the result's node lattice "
                         f"({rows} x {cols} nodes); {widest} already takes every node into "
                         "each fit (strain windows are usually 3 to 15 nodes)")
    table = len(result) * int(window) ** 2 * 8
    if method == "plane_fit" and table > _MAX_TABLE_BYTES:
        raise ValueError(f"window={window} nodes needs a {table / 2**30:.1f} GiB neighbour "
                         f"table for {len(result)} nodes; choose a smaller window "
                         "(strain windows are usually 3 to 15 nodes)")


def compute_strain(result: DICResult, window: int = StrainParams.window,
                   method: str = StrainParams.method, measure: str = StrainParams.measure,
                   roi=None) -> StrainResult:
    """Strain at the nodes of ``result``.

    Parameters
    ----------
    result : DICResult
    window : int
        Strain window in nodes (odd, >= 3) for ``plane_fit``; the virtual
        strain gauge is ``(window - 1) * step + subset`` pixels.
    method : {"plane_fit", "fem"}
    measure : {"infinitesimal", "green_lagrange", "euler_almansi"}
    roi : (H, W) bool, optional
        ROI for the connectivity test; defaults to the one stored with the
        result (``result.roi``), else the whole image.

    Returns
    -------
    StrainResult

    Raises
    ------
    TypeError
        ``result`` is not a DICResult (e.g. a whole sequence or a file name).
    ValueError
        An unknown method or measure, or a window that is even, under 3, wider
        than the node lattice or too large to hold in memory.
    """
    _check_arguments(result, window, method, measure)
    if roi is None:
        roi = getattr(result, "roi", None)
    if roi is None:
        roi = np.ones(result.image_shape, bool)
    roi = np.asarray(roi, bool)
    step = result.params.step
    use = np.asarray(result.valid, bool)
    if method == "plane_fit":
        from .outliers import lattice_neighbours

        nbrs = lattice_neighbours(_grid_of(result), roi, radius=(window - 1) // 2)
        G = np.empty((len(result), 4))
        plane_fit(result.x.astype(float), result.y.astype(float), result.u.astype(float),
                  result.v.astype(float), use, nbrs, 3, G)
        vsg = (window - 1) * step + result.params.subset
    else:
        from .global_solve import Q4Mesh, gradient_operator, uniform_mesh

        if result.elements is not None:
            mesh = Q4Mesh(result.x, result.y, result.elements)
        else:
            mesh = uniform_mesh(_grid_of(result), roi)
        e = mesh.elements
        ok_el = use[e].all(axis=1)  # only elements whose four corners are trusted
        mesh = Q4Mesh(mesh.x, mesh.y, e[ok_el])
        Gx, Gy, covered = gradient_operator(mesh)
        G = np.column_stack([Gx @ result.u, Gy @ result.u, Gx @ result.v, Gy @ result.v])
        G[~(covered & use)] = np.nan
        vsg = 2 * step + result.params.subset
    dudx, dudy, dvdx, dvdy = G.T
    exx, eyy, exy = strain_measures(dudx, dudy, dvdx, dvdy, measure)
    mean = 0.5 * (exx + eyy)
    rad = np.sqrt((0.5 * (exx - eyy)) ** 2 + exy**2)
    e1, e2 = mean + rad, mean - rad
    ezz = -(exx + eyy)
    vm = np.sqrt(2.0 / 3.0 * (exx**2 + eyy**2 + ezz**2 + 2 * exy**2))
    rot = np.arctan2(dvdx - dudy, 2 + dudx + dvdy)
    valid = np.isfinite(exx) & use
    return StrainResult(result.x, result.y, exx, eyy, exy, e1, e2, rad, vm, rot,
                        dudx, dudy, dvdx, dvdy, valid, measure, method, int(window), float(vsg))
