"""Initial displacement guess by FFT normalised cross-correlation (NCC).

For each node, its reference subset (restricted to its mask-connected
component) is slid over a search window of the deformed image and the
zero-normalised cross-correlation is evaluated at every integer shift in
``[-R, R]^2``: the numerator by FFT correlation, the local window energy by
FFT correlation of the subset mask with the window and its square (or by
integral images when the subset is a full square). The peak is refined to
sub-pixel precision with a parabola through its neighbours along each axis.

Nodes are processed in batches whose working memory stays under a fixed
budget, so memory does not grow with the image size. A node whose peak lies
on the border of the tested shifts, or is weak, is searched again with the
range doubled, up to a maximum (automatic widening).

Reference: J. P. Lewis, "Fast normalized cross-correlation", Vision
Interface 1995 (integral-image normalisation); D. Padfield, "Masked object
registration in the Fourier domain", IEEE TIP 21, 2012 (masked NCC).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import fft as sfft

from ..kernels.sums import window_sums

__all__ = ["NCCResult", "ncc_search", "ncc_search_widening"]

_BATCH_BYTES = 48 * 2**20  # working-memory budget of one batch


@dataclass
class NCCResult:
    """Integer-grid NCC search result per node."""

    u: np.ndarray  # sub-pixel displacement along x (pixels)
    v: np.ndarray  # along y
    peak: np.ndarray  # NCC value at the peak, in [-1, 1]; NaN if no valid shift
    on_border: np.ndarray  # bool: peak on the border of the tested range
    search: np.ndarray  # half-range used (pixels)


def _subpixel(c_m, c_0, c_p):
    """Offset (-0.5..0.5) of the vertex of the parabola through three samples
    at -1, 0, 1; 0 where they do not curve downwards."""
    den = c_m - 2.0 * c_0 + c_p
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.where(den < 0, 0.5 * (c_m - c_p) / den, 0.0)
    return np.clip(np.nan_to_num(d), -0.5, 0.5)


def ncc_search(f: np.ndarray, g: np.ndarray, xs: np.ndarray, ys: np.ndarray, half: int,
               search: int, masks: np.ndarray | None = None, cu=None, cv=None,
               workers: int = -1, templates: np.ndarray | None = None) -> NCCResult:
    """NCC search at nodes ``(xs, ys)`` with shifts in ``[-search, search]^2``.

    Parameters
    ----------
    f, g : (H, W) float32
        Reference and deformed images.
    xs, ys : (n,) int
        Node coordinates; the full subset must lie inside ``f``.
    half : int
        Subset half-width h.
    search : int
        Search half-range R in pixels.
    masks : (n, S, S) array or None
        Pixels of each subset to use (None = full squares).
    cu, cv : (n,) int or None
        Integer centre of the search per node (default 0).
    templates : (n, S, S) array or None
        The subsets to look for (default: each node's square of ``f``; a
        rotated copy searches for rotated material).
    """
    n = xs.size
    S = 2 * half + 1
    R = int(search)
    L = S + 2 * R
    N = sfft.next_fast_len(L, real=True)
    cu = np.zeros(n, np.int64) if cu is None else np.asarray(cu, np.int64)
    cv = np.zeros(n, np.int64) if cv is None else np.asarray(cv, np.int64)
    out_u = np.zeros(n)
    out_v = np.zeros(n)
    out_p = np.full(n, np.nan)
    out_b = np.zeros(n, bool)
    per_node = N * N * 40 + L * L * 24
    batch = max(1, min(n, _BATCH_BYTES // per_node))
    for b0 in range(0, n, batch):
        sl = slice(b0, min(n, b0 + batch))
        c = _ncc_surface(f, g, xs[sl], ys[sl], cu[sl], cv[sl],
                         None if masks is None else masks[sl], half, R, N, workers,
                         None if templates is None else templates[sl])
        out_u[sl], out_v[sl], out_p[sl], out_b[sl] = _ncc_peak(c, R, cu[sl], cv[sl])
    return NCCResult(out_u, out_v, out_p, out_b, np.full(n, R))


def _search_windows(g, bx, by, cu, cv, half: int, R: int):
    """Search windows ``(B, L, L)`` float32 of the deformed image around the
    nodes (clamped at the border) and the valid shifts ``(B, 2R+1, 2R+1)``:
    those whose subset stays inside the image."""
    S = 2 * half + 1
    rows, cols = g.shape
    nshift = 2 * R + 1
    woff = np.arange(-half - R, half + R + 1)
    wy = by[:, None] + cv[:, None] + woff[None, :]
    wx = bx[:, None] + cu[:, None] + woff[None, :]
    # shifts whose subset would leave the image are invalid
    ok_y = (wy[:, :nshift] >= 0) & (wy[:, S - 1:] <= rows - 1)
    ok_x = (wx[:, :nshift] >= 0) & (wx[:, S - 1:] <= cols - 1)
    W = g[np.clip(wy, 0, rows - 1)[:, :, None], np.clip(wx, 0, cols - 1)[:, None, :]]
    return W.astype(np.float32), ok_y[:, :, None] & ok_x[:, None, :]


def _ncc_surface(f, g, bx, by, cu, cv, masks, half: int, R: int, N: int,
                 workers: int, T=None) -> np.ndarray:
    """ZNCC ``(B, 2R+1, 2R+1)`` of a batch of nodes at every integer shift
    (-inf where the shift is invalid or the window has no texture).

    The numerator is an FFT correlation (size ``N``) of the zero-mean subset
    with the window; the window energy under the subset comes from integral
    images (full squares) or from FFT correlations with the mask."""
    S = 2 * half + 1
    nshift = 2 * R + 1
    T = (_templates(f, bx, by, half) if T is None else T).astype(np.float32)
    M = None if masks is None else masks.astype(np.float32)
    W, ok = _search_windows(g, bx, by, cu, cv, half, R)
    if M is None:
        npx = float(S * S)
        Tz = T - T.mean(axis=(1, 2), keepdims=True)
    else:
        npx = M.sum(axis=(1, 2), keepdims=True)
        Tz = (T - (T * M).sum(axis=(1, 2), keepdims=True) / npx) * M
    tnorm = np.sqrt((Tz.astype(np.float64) ** 2).sum(axis=(1, 2)))
    FW = sfft.rfft2(W, s=(N, N), workers=workers)
    FT = np.conj(sfft.rfft2(Tz, s=(N, N), workers=workers))
    num = sfft.irfft2(FT * FW, s=(N, N), workers=workers)[:, :nshift, :nshift]
    del FT
    if M is None:
        s1, s2 = window_sums(W, S)
        var = s2 - s1 * s1 / npx
    else:
        FM = np.conj(sfft.rfft2(M, s=(N, N), workers=workers))
        s1 = sfft.irfft2(FM * FW, s=(N, N), workers=workers)[:, :nshift, :nshift]
        FW2 = sfft.rfft2(W * W, s=(N, N), workers=workers)
        s2 = sfft.irfft2(FM * FW2, s=(N, N), workers=workers)[:, :nshift, :nshift]
        del FM, FW2
        var = s2.astype(np.float64) - s1.astype(np.float64) ** 2 / npx
    del FW
    den = tnorm[:, None, None] * np.sqrt(np.maximum(var, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.where(den > 1e-9 * (tnorm[:, None, None] + 1e-30) * np.sqrt(npx) + 1e-12,
                     num / den, -np.inf)
    c[~ok] = -np.inf
    return c


def _ncc_peak(c: np.ndarray, R: int, cu, cv):
    """Peak of each correlation surface, refined to sub-pixel precision by a
    parabola through its neighbours along each axis (where they exist).

    Returns ``(u, v, peak, on_border)``; ``u = v = 0`` and ``peak = NaN``
    where no shift is valid."""
    B = c.shape[0]
    nshift = 2 * R + 1
    flat = c.reshape(B, -1)
    k = np.argmax(flat, axis=1)
    iy, ix = np.divmod(k, nshift)
    best = flat[np.arange(B), k]
    good = np.isfinite(best)
    iym = np.clip(iy - 1, 0, nshift - 1)
    iyp = np.clip(iy + 1, 0, nshift - 1)
    ixm = np.clip(ix - 1, 0, nshift - 1)
    ixp = np.clip(ix + 1, 0, nshift - 1)
    ar = np.arange(B)
    cym, cyp = c[ar, iym, ix], c[ar, iyp, ix]
    cxm, cxp = c[ar, iy, ixm], c[ar, iy, ixp]
    inner_y = (iy > 0) & (iy < nshift - 1) & np.isfinite(cym) & np.isfinite(cyp)
    inner_x = (ix > 0) & (ix < nshift - 1) & np.isfinite(cxm) & np.isfinite(cxp)
    dy = np.where(inner_y,
                  _subpixel(np.where(inner_y, cym, 0), best, np.where(inner_y, cyp, 0)), 0.0)
    dx = np.where(inner_x,
                  _subpixel(np.where(inner_x, cxm, 0), best, np.where(inner_x, cxp, 0)), 0.0)
    u = np.where(good, ix - R + cu + dx, 0.0)
    v = np.where(good, iy - R + cv + dy, 0.0)
    peak = np.where(good, best, np.nan)
    on_border = good & ((ix == 0) | (ix == nshift - 1) | (iy == 0) | (iy == nshift - 1))
    return u, v, peak, on_border


def _templates(f, xs, ys, half: int) -> np.ndarray:
    """The nodes' square subsets ``(n, 2 half + 1, 2 half + 1)`` of ``f``."""
    off = np.arange(-half, half + 1)
    return f[ys[:, None, None] + off[None, :, None], xs[:, None, None] + off[None, None, :]]


def _flat_templates(f, xs, ys, half: int, masks=None, templates=None) -> np.ndarray:
    """Whether each node's subset (its ``templates`` when given; the pixels
    of ``masks``) is one grey level: :func:`_ncc_surface` gives it no valid
    shift, whatever the window."""
    t = np.asarray(_templates(f, xs, ys, half) if templates is None else templates,
                   np.float64)
    if masks is None:
        return np.ptp(t, axis=(1, 2)) == 0
    use = np.asarray(masks, bool)
    hi = np.where(use, t, -np.inf).max(axis=(1, 2))
    lo = np.where(use, t, np.inf).min(axis=(1, 2))
    return ~(hi > lo)


def ncc_search_widening(f, g, xs, ys, half, search, search_max, masks=None,
                        accept=0.5, workers: int = -1, templates=None,
                        cu=None, cv=None) -> NCCResult:
    """NCC search that doubles the range for nodes whose peak is on the
    border of the tested shifts or below ``accept`` (a number, or one per
    node), up to ``search_max``.

    A wider search only replaces a result when its peak is higher. At the
    widest range ``on_border`` stays set where the peak is on its border
    (the motion is probably beyond it). ``cu, cv`` (integers per node)
    centre every range on a predicted displacement (default 0).
    """
    res = ncc_search(f, g, xs, ys, half, search, masks, cu, cv, workers=workers,
                     templates=templates)
    R = search
    # a flat subset has no peak at any range: it is settled at the widest one
    # without searching it there (a saturated region of the crack sample)
    flat = np.zeros(xs.size, bool)
    if R < search_max:
        nan = np.nonzero(~np.isfinite(res.peak))[0]
        flat[nan] = _flat_templates(f, xs[nan], ys[nan], half,
                                    None if masks is None else masks[nan],
                                    None if templates is None else templates[nan])
        res.search[flat] = search_max
    while R < search_max:
        redo = np.nonzero((res.on_border | ~(res.peak >= accept)) & ~flat)[0]
        if redo.size == 0:
            break
        R = min(2 * R, search_max)
        sub = ncc_search(f, g, xs[redo], ys[redo], half, R,
                         None if masks is None else masks[redo],
                         None if cu is None else np.asarray(cu)[redo],
                         None if cv is None else np.asarray(cv)[redo], workers=workers,
                         templates=None if templates is None else templates[redo])
        better = ~(sub.peak <= res.peak[redo])  # NaN-safe: take sub when old is NaN
        better &= np.isfinite(sub.peak)
        take = redo[better]
        res.u[take] = sub.u[better]
        res.v[take] = sub.v[better]
        res.peak[take] = sub.peak[better]
        res.on_border[take] = sub.on_border[better]
        res.search[redo] = R
        # nodes whose wider search did not improve are settled
        res.on_border[redo[~better]] = False
    return res
