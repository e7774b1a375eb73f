"""Local DVC of volumes larger than memory, block by block.

The node lattice of the whole volume is cut into blocks of about ``block``
voxels a side. Each block reads only its window of the two volumes (slicing
a zarr array, a tiled TIFF opened by :func:`~..io.volumes.open_volume`, a
memory-mapped ``.npy`` or any array-like), solves its nodes with the Local
solver of :mod:`.local` and keeps the nodes it owns. Peak memory follows the
window, not the volume.

Why the blocks give the whole volume's result (to the IC-GN tolerance):

* halo -- a window reaches ``subset/2 + 2 + search + 12`` voxels beyond its
  nodes: every subset displaced by up to ``search`` voxels stays inside it
  clear of the window's faces (where the mirror boundary of the spline
  would bias it), and the tricubic prefilter, a recursive filter whose
  influence falls by ``2 - sqrt 3 = 0.27`` a voxel, sees 12 more voxels
  (``0.27^12 = 1.4e-7``, the float32 rounding of the stored coefficients),
  so its coefficients are the whole volume's;
* one ring of lattice nodes beyond the block is solved too, so the median
  test of the nodes at a block's border has all its neighbours.

Each block finds its own initial guess (rigid shift of its centre, anchors):
motion over ``search`` voxels needs a larger ``search`` (and halo).

AL-DVC by blocks: the merged per-node state (warps, uncertainties and each
subset's Gauss-Newton rows) is all its ADMM needs, because its local step
works on each subset's Gauss-Newton model about the Local optimum
(:func:`~.aldvc.solve_aldvc`), never on the voxels: the global step then
couples every node of the volume in memory proportional to the nodes.
"""

from __future__ import annotations

import time

import numpy as np

from ..core.params import DICParams
from ..core.reasons import Reason
from .grid import VolumeGrid, make_volume_grid
from .local import NODE_ARRAYS, NodeState, solve_local_volume
from .validity import final_reasons

__all__ = ["correlate_blocks", "block_halo"]

_FILTER_HALO = 12  # voxels of prefilter context (0.27^12 = 1.4e-7: float32 rounding)


def block_halo(params: DICParams) -> int:
    """Voxels a block's window reaches beyond its outermost nodes."""
    return params.subset // 2 + 2 + params.search + _FILTER_HALO


def _ranges(n: int, per: int):
    return [(a, min(a + per, n)) for a in range(0, n, per)]


def _window(coords, lo, hi, halo, size):
    """Voxel slice covering lattice nodes ``lo:hi`` of ``coords`` and the halo."""
    return max(int(coords[lo]) - halo, 0), min(int(coords[hi - 1]) + halo + 1, size)


def _read(vol, win) -> np.ndarray:
    (z0, z1), (y0, y1), (x0, x1) = win
    return np.ascontiguousarray(np.asarray(vol[z0:z1, y0:y1, x0:x1]), np.float32)


def _block(ref, dfm, roi, whole: VolumeGrid, lat, params, halo, shape):
    """Solve one block: ``lat`` = ((iz0, iz1), (iy0, iy1), (ix0, ix1)) owned
    lattice ranges. Returns (global node indices, state rows, reasons)."""
    axes = (whole.zs, whole.ys, whole.xs)
    sizes = [len(a) for a in axes]
    ext = [(max(a - 1, 0), min(b + 1, n)) for (a, b), n in zip(lat, sizes)]
    win = [_window(c, a, b, halo, s) for c, (a, b), s in zip(axes, ext, shape)]
    f, g = _read(ref, win), _read(dfm, win)
    if roi is None:
        mask = np.ones(f.shape, np.uint8)
    else:
        mask = np.ascontiguousarray(np.asarray(_read(roi, win)) != 0).astype(np.uint8)
    iz, iy, ix = np.meshgrid(*(np.arange(b - a) for a, b in ext), indexing="ij")
    iz, iy, ix = iz.ravel(), iy.ravel(), ix.ravel()
    local_axes = [c[a:b] - w[0] for c, (a, b), w in zip(axes, ext, win)]
    keep = mask[local_axes[0][iz], local_axes[1][iy], local_axes[2][ix]] > 0
    grid = VolumeGrid(local_axes[2], local_axes[1], local_axes[0], ix[keep], iy[keep], iz[keep])
    if grid.n == 0:
        return None
    st = solve_local_volume(f, g, mask, grid, params, None)
    reason = final_reasons(st)
    gz, gy, gx = grid.iz + ext[0][0], grid.iy + ext[1][0], grid.ix + ext[2][0]
    own = ((gz >= lat[0][0]) & (gz < lat[0][1]) & (gy >= lat[1][0]) & (gy < lat[1][1])
           & (gx >= lat[2][0]) & (gx < lat[2][1]))
    return (gz[own], gy[own], gx[own]), st, own, reason[own]


def correlate_blocks(ref, dfm, roi, params: DICParams, block: int, report):
    """The Local solve of the whole lattice by blocks; returns ``(state,
    reason, meta)``: the merged :class:`~.local.NodeState` of the solved
    nodes and their Local reasons."""
    t0 = time.perf_counter()
    shape = tuple(int(s) for s in ref.shape)
    if tuple(dfm.shape) != shape or len(shape) != 3:
        raise ValueError(f"the reference {tuple(ref.shape)} and deformed {tuple(dfm.shape)} "
                         "volumes must be 3-D (z, y, x) of one shape")
    if roi is not None and tuple(roi.shape) != shape:
        raise ValueError(f"the ROI has shape {tuple(roi.shape)} but the volumes {shape}")
    whole = make_volume_grid(shape, params.subset, params.step, None)
    index = np.full(whole.shape, -1, np.int64)
    n = whole.n
    st = NodeState(whole, params, report=report)
    reason = np.full(n, Reason.NO_INITIAL_GUESS, np.int8)
    solved = np.zeros(n, bool)
    per = max(int(block) // params.step, 1)
    blocks = [(a, b, c) for a in _ranges(whole.shape[0], per)
              for b in _ranges(whole.shape[1], per) for c in _ranges(whole.shape[2], per)]
    halo = block_halo(params)
    index[whole.iz, whole.iy, whole.ix] = np.arange(n)
    end = 0.5 if params.method == "aldic" else 0.95
    for k, lat in enumerate(blocks):
        report("icgn", 0.05 + (end - 0.05) * k / len(blocks), f"block {k + 1}/{len(blocks)}")
        out = _block(ref, dfm, roi, whole, lat, params, halo, shape)
        if out is None:
            continue
        (gz, gy, gx), bst, own, r = out
        j = index[gz, gy, gx]
        for name in NODE_ARRAYS:
            getattr(st, name)[j] = getattr(bst, name)[own]
        reason[j] = r
        solved[j] = True
    grid = VolumeGrid(whole.xs, whole.ys, whole.zs, whole.ix[solved], whole.iy[solved],
                      whole.iz[solved])
    meta = {"blocks": len(blocks), "block": int(block), "halo": halo,
            "seconds": time.perf_counter() - t0}
    return st.take(solved, grid), reason[solved], meta
