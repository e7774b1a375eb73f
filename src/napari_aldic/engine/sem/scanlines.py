"""Scan-line shifts: SEM raster lines that jumped along x by a fraction of a
pixel to a pixel, in blocks of a few rows, differently in every image.

Estimation from a pair (docs/sem.md). After a first correlation, the deformed
image is warped into the reference frame with the (smooth) measured field and
each reference row's x-shift against it is found by 1-D Gauss-Newton over the
whole row; the same is done for each deformed row with the reference warped
into the deformed frame. What is left after removing the smooth part (a
running median over rows) is the difference of the two images' line shifts.
Each block of shifted rows is then given to the image in which it is a jump
between neighbouring rows (the row-to-row shift of the image itself), the
rows are resampled, and the pair correlated again (twice by default).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.interpolate import RectBivariateSpline

from ..core.images import as_gray_float
from ..core.params import DICParams
from ..core.results import DICResult
from ..dic.correlate import correlate
from ..dic.interpolation import prefilter, sample

__all__ = ["ScanLines", "estimate_scan_lines", "find_scan_lines", "remove_scan_lines",
           "correlate_scan_lines"]


@dataclass
class ScanLines:
    """x-shift (px) of every row of the reference and of the deformed image:
    row ``y`` of an image shows what belongs at ``x - shift[y]``."""

    reference: np.ndarray
    deformed: np.ndarray

    def to_meta(self) -> dict:
        """Sparse, JSON-ready: rows and shifts of each image's shifted lines."""
        out = {}
        for name in ("reference", "deformed"):
            s = getattr(self, name)
            rows = np.flatnonzero(s)
            out[name] = {"rows": rows.tolist(), "shift_px": [round(float(v), 4) for v in s[rows]]}
        out["n_rows"] = int(self.reference.size)
        return out

    @classmethod
    def from_meta(cls, d: dict) -> ScanLines:
        arrays = []
        for name in ("reference", "deformed"):
            a = np.zeros(int(d["n_rows"]))
            a[np.asarray(d[name]["rows"], int)] = d[name]["shift_px"]
            arrays.append(a)
        return cls(*arrays)


def remove_scan_lines(image, shifts) -> np.ndarray:
    """The image with row ``y`` resampled at ``x + shifts[y]`` (cubic B-spline)."""
    f = as_gray_float(image)
    shifts = np.asarray(shifts, float)
    if shifts.shape != (f.shape[0],):
        raise ValueError(f"{shifts.size} scan-line shifts for an image of {f.shape[0]} rows")
    if not np.any(shifts):
        return f
    yy, xx = np.mgrid[0:f.shape[0], 0:f.shape[1]].astype(float)
    return sample(prefilter(f), np.clip(xx + shifts[:, None], 0, f.shape[1] - 1), yy)


def _row_shifts(a: np.ndarray, b: np.ndarray, weight: np.ndarray, iters: int = 4) -> np.ndarray:
    """Per row, the shift ``r`` with ``b(x) ~ a(x - r)`` (row means removed),
    by Gauss-Newton over the pixels of ``weight``."""
    spl = prefilter(a)
    yy, xx = np.mgrid[0:a.shape[0], 0:a.shape[1]].astype(float)
    r = np.zeros(a.shape[0])
    bw = b - (b * weight).sum(1, keepdims=True) / np.maximum(weight.sum(1, keepdims=True), 1)
    for _ in range(iters):
        a_s = sample(spl, np.clip(xx - r[:, None], 0, a.shape[1] - 1), yy)
        a_s = a_s - (a_s * weight).sum(1, keepdims=True) / np.maximum(
            weight.sum(1, keepdims=True), 1)
        ax = np.gradient(a_s, axis=1)
        e = bw - a_s
        den = (weight * ax * ax).sum(1)
        step = -(weight * e * ax).sum(1) / np.maximum(den, 1e-9)
        r += np.where(den > 0, np.clip(step, -1.5, 1.5), 0.0)
    return r


def _dense(result: DICResult, shape):
    """Cubic-spline interpolants of u and v over the node lattice (untrusted
    nodes filled from the nearest trusted one), and the covered pixel box."""
    xs, ys = np.asarray(result.grid_xs, float), np.asarray(result.grid_ys, float)
    on = (result.grid_ix >= 0) & (result.grid_iy >= 0)
    U = np.full((ys.size, xs.size), np.nan)
    V = np.full_like(U, np.nan)
    ok = on & result.valid & np.isfinite(result.u)
    U[result.grid_iy[ok], result.grid_ix[ok]] = result.u[ok]
    V[result.grid_iy[ok], result.grid_ix[ok]] = result.v[ok]
    if not np.isfinite(U).any():
        raise ValueError("no trusted node: cannot estimate scan-line shifts")
    idx = ndimage.distance_transform_edt(~np.isfinite(U), return_distances=False,
                                         return_indices=True)
    U, V = U[tuple(idx)], V[tuple(idx)]
    k = min(3, xs.size - 1, ys.size - 1)
    return (RectBivariateSpline(ys, xs, U, kx=k, ky=k), RectBivariateSpline(ys, xs, V, kx=k, ky=k),
            (int(np.ceil(xs[0])), int(np.floor(xs[-1])), int(np.ceil(ys[0])),
             int(np.floor(ys[-1]))))


def _covered(weight: np.ndarray) -> tuple[int, int]:
    """First and last row with material over at least half the width."""
    rows = np.flatnonzero(weight.sum(1) >= 0.5 * weight.shape[1])
    return (int(rows[0]), int(rows[-1])) if rows.size else (0, -1)


def _residuals(f: np.ndarray, g: np.ndarray, result: DICResult, roi=None):
    """Row shifts ``L_def - L_ref`` in reference rows and in deformed rows
    (over the ROI of the reference, carried into the deformed frame; the
    field is extrapolated beyond the outer nodes), the mean v of every
    reference row and the rows each residual covers."""
    h, w = f.shape
    su, sv, _ = _dense(result, f.shape)
    xs, ys = np.arange(w, dtype=float), np.arange(h, dtype=float)
    U, V = su(ys, xs), sv(ys, xs)
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    mask = np.ones((h, w), bool) if roi is None else np.asarray(roi, bool)
    # reference frame: the deformed image pulled back by the field
    px, py = xx + U, yy + V
    w_ref = mask & (px >= 0) & (px <= w - 1) & (py >= 0) & (py <= h - 1)
    g_w = sample(prefilter(g), np.clip(px, 0, w - 1), np.clip(py, 0, h - 1))
    r_ref = _row_shifts(f, g_w, w_ref.astype(float))
    # deformed frame: X with X + u(X) = x, by fixed point
    X, Y = xx.copy(), yy.copy()
    for _ in range(4):
        X, Y = xx - su.ev(Y, X), yy - sv.ev(Y, X)
    w_def = (X >= 0) & (X <= w - 1) & (Y >= 0) & (Y <= h - 1)
    w_def &= mask[np.clip(np.rint(Y).astype(int), 0, h - 1),
                  np.clip(np.rint(X).astype(int), 0, w - 1)]
    f_w = sample(prefilter(f), np.clip(X, 0, w - 1), np.clip(Y, 0, h - 1))
    r_def = _row_shifts(f_w, g, w_def.astype(float))
    return r_ref, r_def, np.median(V, axis=1), _covered(w_ref), _covered(w_def)


def _steps(image: np.ndarray) -> np.ndarray:
    """Row-to-row x-shift of one image: ``steps[y]`` is row y against row y-1."""
    out = np.zeros(image.shape[0])
    out[1:] = _row_shifts(image[:-1], image[1:], np.ones_like(image[1:]), iters=2)
    return out


def _sparse(r: np.ndarray, subset: int, rows, min_shift: float):
    """The sparse part of ``r`` and the rows beyond the threshold.

    The first correlation itself smoothed every line shift over a subset's
    rows, so ``r ~ s - box * s + smooth`` with ``s`` the sparse shifts: ``s``
    is found by fixed point, adding the subset average of the current ``s``
    back before the running median removes what is smooth."""
    lo, hi = rows
    s = np.zeros_like(r)
    flag = np.zeros(r.size, bool)
    if hi - lo < 2 * subset:  # too few rows with material to tell jumps from motion
        return s, flag
    for _ in range(6):
        q = r + ndimage.uniform_filter1d(s, size=subset, mode="nearest")
        hp = q - ndimage.median_filter(q, size=2 * subset + 1, mode="nearest")
        core = hp[lo:hi + 1]
        sigma = 1.4826 * np.median(np.abs(core - np.median(core)))
        flag[:] = False
        flag[lo:hi + 1] = np.abs(core) > max(min_shift, 5 * sigma)
        s = np.where(flag, hp, 0.0)
    return hp, flag


def estimate_scan_lines(reference, deformed, result: DICResult,
                        min_shift: float = 0.08, roi=None) -> ScanLines:
    """Line shifts of both images from their correlation ``result`` (shifts
    under ``min_shift`` px, or under five robust standard deviations of the
    row residuals, are taken as none)."""
    f, g = as_gray_float(reference, "reference"), as_gray_float(deformed, "deformed")
    r_ref, r_def, rows_v, rows_ref, rows_def = _residuals(f, g, result, roi)
    subset = result.params.subset
    hp_ref, flag_ref = _sparse(r_ref, subset, rows_ref, min_shift)
    hp_def, flag_def = _sparse(r_def, subset, rows_def, min_shift)
    s_ref, s_def = _steps(f), _steps(g)
    L_ref, L_def = np.zeros(f.shape[0]), np.zeros(f.shape[0])
    labels, _ = ndimage.label(flag_ref)
    for blk in ndimage.find_objects(labels):
        a, b = blk[0].start, blk[0].stop - 1
        m = float(hp_ref[a:b + 1].mean())
        score_ref = m * (s_ref[min(b + 1, f.shape[0] - 1)] - s_ref[a])
        lo = int(np.floor(a + rows_v[a])) - 1
        hi = int(np.ceil(b + rows_v[b])) + 1
        lo, hi = max(lo, 0), min(hi, f.shape[0] - 1)
        drows = np.flatnonzero(flag_def[lo:hi + 1]) + lo
        score_def = -np.inf
        if drows.size:
            a2, b2 = drows[0], drows[-1]
            score_def = m * (s_def[a2] - s_def[min(b2 + 1, f.shape[0] - 1)])
        if score_ref >= score_def:
            L_ref[a:b + 1] = -hp_ref[a:b + 1]
        else:
            L_def[drows] = hp_def[drows]
    return ScanLines(L_ref, L_def)


def find_scan_lines(reference, deformed, roi=None, params: DICParams | None = None,
                    passes: int = 2, min_shift: float = 0.08) -> ScanLines:
    """Both images' line shifts by ``passes`` rounds of (correlate on a lattice
    of at most 8 px, estimate, remove)."""
    params = params or DICParams()
    f, g = as_gray_float(reference, "reference"), as_gray_float(deformed, "deformed")
    coarse = dataclasses.replace(params, step=min(params.step, 8), method="local")
    lines = ScanLines(np.zeros(f.shape[0]), np.zeros(f.shape[0]))
    fc, gc = f, g
    for _ in range(passes):
        res = correlate(fc, gc, roi=roi, params=coarse)
        more = estimate_scan_lines(fc, gc, res, min_shift, roi)
        if not (np.any(more.reference) or np.any(more.deformed)):
            break
        lines = ScanLines(lines.reference + more.reference, lines.deformed + more.deformed)
        fc, gc = remove_scan_lines(f, lines.reference), remove_scan_lines(g, lines.deformed)
    return lines


def correlate_scan_lines(reference, deformed, roi=None, params: DICParams | None = None,
                         passes: int = 2, min_shift: float = 0.08):
    """Correlate a pair with its scan-line shifts estimated
    (:func:`find_scan_lines`) and removed. Returns ``(result, ScanLines)``;
    the shifts are recorded in ``result.meta["sem"]["scan_lines"]``."""
    lines = find_scan_lines(reference, deformed, roi, params, passes, min_shift)
    res = correlate(remove_scan_lines(reference, lines.reference),
                    remove_scan_lines(deformed, lines.deformed), roi=roi,
                    params=params or DICParams())
    res.meta.setdefault("sem", {})["scan_lines"] = lines.to_meta()
    return res, lines
