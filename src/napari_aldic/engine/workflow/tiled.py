"""DIC of an image pair larger than memory, block by block.

The node lattice of the whole image is cut into blocks of about
``tile_size`` pixels a side. Each block reads only its window of the two
images (plus a halo), runs :func:`~napari_aldic.engine.correlate` on it and
writes the nodes it owns into node arrays of the whole lattice (in memory, or
memory-mapped ``.npy`` files under ``out_dir``); peak memory depends on the
block size, not on the image size. Node arrays of a 40,000 px image at step
32 (1250 x 1250 nodes) are small; its images (1.6 GB each as 8-bit, four
times that as the float arrays DIC needs) are never held whole.

Why the blocks give the untiled result:

* halo -- a block's window reaches ``subset/2 + 1 + search_max + 48`` pixels
  beyond its nodes: every subset and every searched shift lies inside it, and
  the B-spline prefilter (a recursive filter whose influence decays by at
  least 0.43 per pixel) sees 48 more pixels, so its coefficients equal the
  whole image's to float precision; a halo of :data:`NODE_HALO` lattice nodes
  gives the outlier test and the repair of neighbours the same neighbours;
* the same choices everywhere -- ``search_max`` (``4 * search`` unless set)
  and the interpolation order (from the middle of the reference) are fixed
  once for the pair, not per block;
* one initial guess -- a spatially propagated guess would differ near block
  borders, so a coarse pass first correlates a sparse lattice (every
  ``guess_spacing`` pixels, same blocks), and every node of every block then
  starts from the same coarse result (``correlate(..., guess=...)``): its
  nearest valid coarse node, extrapolated to first order.

Block statistics that the validity tests take from their nodes (the median
match residual) are each block's own: a node near a threshold may be flagged
differently from an untiled run; the image noise is the whole pair's. With
``method="aldic"`` the Local result then goes through AL-DIC, its local step
read block by block (:mod:`.tiled_aldic`). Seed propagation and mesh
refinement need the whole image and are refused.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numba
import numpy as np

from ..core.params import DICParams
from ..core.progress import check_cancel
from ..core.reasons import DICError, Reason
from ..core.results import DICResult
from ..dic.correlate import correlate
from ..dic.icgn import convergence_record
from ..dic.interpolation import PREFILTER_MARGIN, choose_order, jacobian_smoothing
from ..dic.mesh import EDGE
from ..dic.reliability import image_noise
from ..io.stack import open_image
from .tiled_aldic import aldic_tiled

__all__ = ["correlate_tiled", "coarse_guess", "needs_tiling", "AUTO_TILE_PIXELS",
           "DEFAULT_TILE", "NODE_HALO", "PREFILTER_MARGIN"]

#: pixels per image above which ``needs_tiling`` says yes: about 2 GiB of
#: working arrays for an untiled run
AUTO_TILE_PIXELS = 40_000_000
#: owned pixels per block side by default
DEFAULT_TILE = 2048
#: lattice nodes correlated around a block's own nodes (outlier test: 2)
NODE_HALO = 4
#: the per-node arrays of a result written block by block (optional
#: DICResult fields that a block may leave None are NaN)
_FIELDS = {"u": np.float64, "v": np.float64, "dudx": np.float64, "dudy": np.float64,
           "dvdx": np.float64, "dvdy": np.float64, "zncc": np.float64,
           "reason": np.int8, "iterations": np.int32, "present": bool}
_OPTIONAL = tuple(k for k in ("u_std", "v_std", "sssig", "mig")
                  if k in DICResult.__dataclass_fields__)
_FIELDS.update({k: np.float64 for k in _OPTIONAL})


def needs_tiling(shape, threshold: int = AUTO_TILE_PIXELS) -> bool:
    """Whether an image pair of ``shape`` should be correlated in blocks."""
    return int(shape[0]) * int(shape[1]) > threshold


@dataclass
class _Plan:
    """The lattice of the whole image and how blocks cut it."""

    shape: tuple[int, int]
    xs: np.ndarray
    ys: np.ndarray
    step: int
    per_block: int  # owned lattice nodes per block side
    halo_nodes: int
    margin: int  # pixels beyond the outermost node of a block's window

    def blocks(self):
        """``(iy0, iy1, ix0, ix1)`` owned lattice index ranges, row by row."""
        for iy0 in range(0, self.ys.size, self.per_block):
            for ix0 in range(0, self.xs.size, self.per_block):
                yield (iy0, min(self.ys.size, iy0 + self.per_block),
                       ix0, min(self.xs.size, ix0 + self.per_block))

    @property
    def n_blocks(self) -> int:
        return math.ceil(self.ys.size / self.per_block) * math.ceil(self.xs.size / self.per_block)

    def window(self, i0: int, i1: int, axis: int):
        """Image window ``(lo, hi)`` along ``axis`` of owned indices
        ``[i0, i1)``: the halo nodes plus ``margin``, starting on a multiple of
        ``step`` so that the window's own lattice is the global one."""
        c = self.ys if axis == 0 else self.xs
        a = c[max(0, i0 - self.halo_nodes)]
        b = c[min(c.size - 1, i1 - 1 + self.halo_nodes)]
        lo = max(0, (a - self.margin) // self.step * self.step)
        return int(lo), int(min(self.shape[axis], b + self.margin + 1)), int(a), int(b)


def _plan(shape, params: DICParams, tile_size: int) -> _Plan:
    h = params.half
    m = h + EDGE
    xs = np.arange(m, shape[1] - m, params.step, dtype=np.int64)
    ys = np.arange(m, shape[0] - m, params.step, dtype=np.int64)
    if xs.size == 0 or ys.size == 0:
        raise DICError("subset_too_large", f"subset={params.subset} px is larger than the "
                       f"image ({shape[0]} x {shape[1]} px); choose a smaller subset",
                       subset=params.subset, shape=tuple(shape))
    halo = max(NODE_HALO, math.ceil((h + 1) / params.step) + 2)
    per_block = max(1, int(tile_size) // params.step)
    margin = m + int(params.search_max) + PREFILTER_MARGIN
    return _Plan((int(shape[0]), int(shape[1])), xs, ys, params.step, per_block, halo, margin)


def _counted(res: DICResult, params: DICParams) -> DICResult:
    """``res`` with the counts an untiled run records: nodes, valid nodes and
    how IC-GN converged over all blocks."""
    res.meta["n_nodes"] = len(res)
    res.meta["n_valid"] = res.n_valid
    res.meta["convergence"] = convergence_record(
        res.reason, res.iterations, res.reason != Reason.SMALL_COMPONENT, params.max_iter)
    return res


def _shared(params: DICParams, ref, dfm, roi) -> DICParams:
    """``params`` with what every block takes from the whole pair: its image
    noise (the validity tests judge every node against it, as an untiled run
    does), and that the guess is this same pair's coarse result (IC-GN starts
    from it directly, without the search around a previous frame's field)."""
    image_var = 0.5 * (image_noise(ref, roi) ** 2 + image_noise(dfm, roi) ** 2)
    return params.replace(extra={**params.extra, "image_var": image_var,
                                 "guess_of_this_pair": True})


def _resolved(params: DICParams, ref, shape) -> DICParams:
    """The choices every block must share: ``search_max`` and the B-spline order."""
    if params.init != "fft":
        raise ValueError("seed propagation spreads over the whole image; tiled runs use the "
                         "FFT initial guess (init='fft')")
    if params.refine not in (None, "none"):
        raise ValueError("mesh refinement is not available for tiled runs; use refine=None")
    changes = {}
    if params.search_max is None:
        changes["search_max"] = 4 * params.search
    # speckle_scale and jacobian_smoothing read the central 512² of their image:
    # this window gives them exactly the crop an untiled run would measure
    r0, c0 = max(0, shape[0] // 2 - 512), max(0, shape[1] // 2 - 512)
    middle = np.asarray(ref[r0:r0 + 1024, c0:c0 + 1024], np.float64)
    if params.interpolation == "auto":
        changes["interpolation"] = "quintic" if choose_order("auto", middle) == 5 else "cubic"
    # every block smooths its steepest-descent images with the whole pair's value
    # (a new dict: replace() would share the caller's)
    changes["extra"] = {**params.extra, "jacobian_sigma": jacobian_smoothing(middle)}
    return params.replace(**changes)


def _block(ref, dfm, roi, plan: _Plan, bounds, params: DICParams, guess):
    """Correlate one block; its owned nodes as ``(iy, ix, fields)`` (None: no node)."""
    iy0, iy1, ix0, ix1 = bounds
    r0, r1, ya, yb = plan.window(iy0, iy1, 0)
    c0, c1, xa, xb = plan.window(ix0, ix1, 1)
    h = params.half
    band = np.zeros((r1 - r0, c1 - c0), bool)
    band[max(0, ya - h - r0):yb + h + 1 - r0, max(0, xa - h - c0):xb + h + 1 - c0] = True
    if roi is not None:
        band &= np.asarray(roi[r0:r1, c0:c1]) != 0
    if not band.any():
        return None
    g = None if guess is None else replace(guess, x=guess.x - c0, y=guess.y - r0)
    try:
        res = correlate(ref[r0:r1, c0:c1], dfm[r0:r1, c0:c1], roi=band, params=params, guess=g)
    except ValueError as exc:
        if "no node" in str(exc):  # the ROI leaves no node in this block
            return None
        if "blank" not in str(exc):
            raise
        return _failed_block(plan, bounds, band, r0, c0)
    ix = (res.x.astype(np.int64) + c0 - plan.xs[0]) // plan.step
    iy = (res.y.astype(np.int64) + r0 - plan.ys[0]) // plan.step
    own = (ix >= ix0) & (ix < ix1) & (iy >= iy0) & (iy < iy1)
    fields = {k: (np.full(int(own.sum()), np.nan) if getattr(res, k) is None
                  else getattr(res, k)[own]) for k in _FIELDS if k != "present"}
    return iy[own], ix[own], fields, res.meta


def _failed_block(plan: _Plan, bounds, band, r0, c0):
    """Owned nodes of a block whose window cannot be correlated (e.g. blank):
    present, not valid (NO_TEXTURE)."""
    iy0, iy1, ix0, ix1 = bounds
    gy, gx = np.meshgrid(np.arange(iy0, iy1), np.arange(ix0, ix1), indexing="ij")
    gy, gx = gy.ravel(), gx.ravel()
    inside = band[plan.ys[gy] - r0, plan.xs[gx] - c0]
    gy, gx = gy[inside], gx[inside]
    n = gy.size
    fields = {k: np.zeros(n, dt) for k, dt in _FIELDS.items() if k != "present"}
    for k in ("zncc",) + _OPTIONAL:
        fields[k][:] = np.nan
    fields["reason"][:] = Reason.NO_TEXTURE
    return gy, gx, fields, {}


def _node_arrays(shape, out_dir):
    """The lattice arrays results are written into: memory-mapped ``.npy``
    files under ``out_dir``, or plain arrays."""
    if out_dir is None:
        return {k: np.zeros(shape, dt) for k, dt in _FIELDS.items()}
    folder = Path(out_dir)
    folder.mkdir(parents=True, exist_ok=True)
    return {k: np.lib.format.open_memmap(folder / f"{k}.npy", mode="w+", dtype=dt, shape=shape)
            for k, dt in _FIELDS.items()}


def _run_blocks(ref, dfm, roi, plan: _Plan, params: DICParams, guess, workers: int,
                arrays: dict, progress, cancel, label: str) -> dict:
    """Every block of ``plan``, ``workers`` at a time; results written as they come."""
    total = params.n_threads or numba.get_num_threads()
    bparams = params.replace(n_threads=max(1, total // workers))
    meta: dict = {}
    blocks = list(plan.blocks())
    done = 0

    def one(bounds):
        check_cancel(cancel)
        return _block(ref, dfm, roi, plan, bounds, bparams, guess)

    with ThreadPoolExecutor(max_workers=workers) as pool:
        for out in pool.map(one, blocks):
            done += 1
            _release_freed_memory()
            if out is not None:
                iy, ix, fields, bmeta = out
                for k, val in fields.items():
                    arrays[k][iy, ix] = val
                arrays["present"][iy, ix] = True
                meta = meta or bmeta
            if progress is not None:
                progress(done / len(blocks), f"{label}: block {done}/{len(blocks)}")
    return meta


def _release_freed_memory() -> None:
    """Hand the heap space of a finished block back to the system: glibc keeps
    freed blocks of the worker threads' arenas, and the peak resident memory
    of a long tiled run would creep up with them."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc: nothing to do
        pass


def coarse_guess(reference, deformed, roi=None, params: DICParams | None = None, *,
                 tile_size: int = DEFAULT_TILE, guess_spacing: int | None = None,
                 workers: int = 1, progress=None, cancel=None) -> DICResult:
    """The shared initial guess of a tiled run: Local DIC on a sparse lattice
    (every ``guess_spacing`` pixels; default the larger of the coarse-node
    spacing and ``4 * step``), block by block.

    ``params`` should be resolved as :func:`correlate_tiled` does (it is, when
    this is called from there)."""
    params = params or DICParams()
    ref, dfm = open_image(reference), open_image(deformed)
    spacing = guess_spacing or max(params.resolved_init_spacing(), 4 * params.step)
    spacing = max(params.step, spacing // params.step * params.step)
    # the coarse result only starts the nodes: no speckle-quality maps
    cparams = params.replace(step=spacing, init_spacing=spacing,
                             extra={**params.extra, "quality": False})
    plan = _plan(ref.shape, cparams, max(tile_size, 4 * spacing))
    arrays = _node_arrays(plan.ys.shape + plan.xs.shape, None)
    _run_blocks(ref, dfm, roi, plan, cparams, None, workers, arrays, progress, cancel,
                "initial guess")
    good = arrays["present"] & (arrays["reason"] == Reason.OK)
    if not good.any():
        raise ValueError(
            f"no node of the {spacing} px initial-guess lattice matched between "
            f"{ref.name} and {dfm.name}; the motion may exceed search_max="
            f"{params.search_max} px (raise --search-max) or the images do not match")
    return _assemble(arrays, plan, cparams, {"role": "tiled initial guess"}, good)


def _assemble(arrays: dict, plan: _Plan, params: DICParams, meta: dict,
              keep=None) -> DICResult:
    """A DICResult of the present nodes, in lattice (row-major) order."""
    keep = arrays["present"] if keep is None else keep
    iy, ix = np.nonzero(keep)
    f = {k: np.asarray(arrays[k][iy, ix]) for k in _FIELDS if k != "present"}
    reason = f.pop("reason")
    return DICResult(
        x=plan.xs[ix].astype(np.float64), y=plan.ys[iy].astype(np.float64),
        valid=reason == Reason.OK, reason=reason, grid_ix=ix.astype(np.int64),
        grid_iy=iy.astype(np.int64), grid_xs=plan.xs, grid_ys=plan.ys,
        image_shape=plan.shape, params=params, meta=meta, **f)


def correlate_tiled(reference, deformed, roi=None, subset: int | None = None,
                    step: int | None = None, method: str | None = None, *,
                    params: DICParams | None = None,
                    tile_size: int = DEFAULT_TILE, workers: int = 1,
                    guess: DICResult | None = None, guess_spacing: int | None = None,
                    out_dir=None, progress=None, cancel=None, **kwargs) -> DICResult:
    """DIC of a pair too large for memory, block by block (Local, or AL-DIC
    whose ADMM local step re-reads the blocks: :mod:`.tiled_aldic`).

    Parameters
    ----------
    reference, deformed : path, zarr array, LazyImage or array
        The images (TIFF/BigTIFF, zarr, OME-Zarr: read window by window).
    roi : 2-D array-like or None
        Region of interest (sliced per block: a NumPy, memory-mapped or zarr
        boolean array of the image's shape).
    subset, step, method, params, **kwargs
        As for :func:`~napari_aldic.engine.correlate` (``method="local"`` or
        ``"aldic"``).
    tile_size : int
        Owned pixels per block side (the window adds a halo).
    workers : int
        Blocks correlated at once (threads; the Numba threads are shared
        among them).
    guess : DICResult, optional
        The shared initial guess (default :func:`coarse_guess`).
    out_dir : folder, optional
        Write the node arrays there as memory-mapped ``.npy`` files.
    progress : callable(fraction, message), optional
    cancel : callable() -> bool, optional

    Returns
    -------
    DICResult
        Over the whole image's lattice; ``meta["tiled"]`` describes the blocks.
    """
    t0 = time.perf_counter()
    params = DICParams.combine(params, kwargs, subset=subset, step=step, method=method)
    workers = max(1, int(workers))
    ref, dfm = open_image(reference), open_image(deformed)
    if ref.shape != dfm.shape:
        raise ValueError(f"reference image {ref.name} is {ref.shape[0]} x {ref.shape[1]} px "
                         f"but deformed image {dfm.name} is {dfm.shape[0]} x "
                         f"{dfm.shape[1]} px; they must have the same size")
    if roi is not None and tuple(roi.shape) != ref.shape:
        raise DICError("shape_mismatch", f"ROI mask shape {tuple(roi.shape)} differs from "
                       f"image shape {ref.shape}", what="roi", shape=tuple(roi.shape),
                       image_shape=ref.shape)
    params = _shared(_resolved(params.fitted_to(ref.shape), ref, ref.shape), ref, dfm, roi)
    aldic = params.method == "aldic"
    lparams = params.replace(method="local") if aldic else params
    # fractions of the progress bar: initial guess, Local blocks, (AL-DIC)
    cut1, cut2 = (0.1, 0.4) if aldic else (0.2, 1.0)
    report = progress or (lambda frac, msg: None)
    if guess is None:
        guess = coarse_guess(ref, dfm, roi, lparams, tile_size=tile_size,
                             guess_spacing=guess_spacing, workers=workers, cancel=cancel,
                             progress=lambda f, m: report(cut1 * f, m))
    t_guess = time.perf_counter() - t0
    plan = _plan(ref.shape, lparams, tile_size)
    arrays = _node_arrays(plan.ys.shape + plan.xs.shape, out_dir)
    bmeta = _run_blocks(ref, dfm, roi, plan, lparams, guess, workers, arrays,
                        lambda f, m: report(cut1 + (cut2 - cut1) * f, m), cancel,
                        "correlation")
    meta = {"versions": bmeta.get("versions", {}),
            "interpolation": params.interpolation,
            "tiled": {"tile_size": int(tile_size), "blocks": plan.n_blocks,
                      "workers": workers, "halo_nodes": plan.halo_nodes,
                      "margin_px": plan.margin, "guess_nodes": int(guess.valid.sum()),
                      "reference": ref.name, "deformed": dfm.name},
            "timing": {"guess": t_guess, "total": time.perf_counter() - t0}}
    res = _counted(_assemble(arrays, plan, lparams, meta), params)
    if aldic:
        res = aldic_tiled(ref, dfm, roi, res, params, plan.per_block, workers=workers,
                          cancel=cancel, progress=lambda f, m: report(cut2 + (1 - cut2) * f, m))
        res.meta["timing"]["total"] = time.perf_counter() - t0
    return res
