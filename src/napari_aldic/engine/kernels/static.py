"""Per-node tests for matches that features which do not move can explain.

Two kernels behind :mod:`napari_aldic.engine.dic.static`:

* :func:`zero_motion_evidence` -- compares, pixel by pixel, the subset's ZNSSD
  residual at the found warp with its residual at zero motion: how much of the
  difference between the two explanations speaks for zero motion, and how
  far beyond image noise that is (inlined into the affine IC-GN kernel, which
  has just sampled the subset at its warp);
* :func:`lag_peaks` -- the reference subset's normalised correlation with
  the reference itself around a few candidate lags: a second peak nearly as
  high as the one at zero lag makes the match ambiguous (periodic texture).

Each subset is gathered as IC-GN gathers it (the node's mask component
only).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .flags import FASTMATH, INLINE, SERIAL, SERIAL_CALLEE

__all__ = ["zero_motion_evidence", "lag_peaks"]

_INV_SQRT_2PI = 0.3989422804014327

#: the standard normal density φ(t) and tail Φ(-t) tabulated on t = i / 64,
#: 0 <= t <= 10 (beyond, both are below 1e-22): the per-pixel moments of
#: :func:`_positive_part_moments` interpolate them instead of calling exp and
#: erfc, which cost most of the zero-motion test (relative error < 3e-3)
_T_STEP = 64.0
_T_GRID = np.arange(0, 641) / _T_STEP
_PHI = _INV_SQRT_2PI * np.exp(-0.5 * _T_GRID**2)
_TAIL = 0.5 * np.array([math.erfc(t / math.sqrt(2.0)) for t in _T_GRID])


@nb.njit(**INLINE, fastmath=FASTMATH)
def _positive_part_moments(a, b):
    """Mean and second moment of ``max(0, a X - b)``, ``X ~ N(0, 1)``, ``a > 0``:
    with ``t = b / a``, ``E = a φ(t) - b Φ(-t)`` and
    ``E² = (a² + b²) Φ(-t) - a b φ(t)`` (``φ``, ``Φ`` from the tables)."""
    x = b / a * _T_STEP
    if x >= _T_GRID.size - 1:
        return 0.0, 0.0
    i = int(x)
    w = x - i
    phi = _PHI[i] + w * (_PHI[i + 1] - _PHI[i])
    tail = _TAIL[i] + w * (_TAIL[i + 1] - _TAIL[i])
    return a * phi - b * tail, (a * a + b * b) * tail - a * b * phi


# called once per node: compiled once as a function (shared by the IC-GN kernels,
# ~2 s less compiling), not inlined; the call costs nothing measurable
@nb.njit(**SERIAL_CALLEE, fastmath=FASTMATH)
def zero_motion_evidence(g, x0, y0, dxs, dys, fs, gp, m, var_img, g0, dbuf, min_fraction):
    """How strongly part of a subset prefers zero motion to its found warp.

    With the subsets zero-normalised (ZNSSD), ``e = f̂ - ĝ_p`` the residual at
    the found warp and ``Δ = ĝ_0 - ĝ_p`` how the deformed subset changes from
    the warp to zero motion, a pixel's residual at zero motion minus that at
    the warp is ``Δ² - 2 e Δ``. The sum of its negative parts,
    ``S = Σ max(0, 2 e Δ - Δ²)``, is the evidence for zero motion; ``D = Σ Δ²``
    is what tells the two explanations apart. Under pure noise (``e``
    Gaussian, standard deviation ``s`` from the image noise) each term of
    ``S`` has a known mean and variance (positive part of a Gaussian), so
    ``z = (S - E S) / sd S`` measures how far beyond noise the evidence is.
    IC-GN calls it on a converged node with the samples of its last step.
    ``z`` is computed only where ``S / D > min_fraction`` (its per-pixel
    moments cost most of the test; a node at or below the fraction is never
    flagged, whatever ``z``).

    Parameters
    ----------
    g : (H, W) float32
        Deformed image (its values at zero motion).
    x0, y0 : int
        Node pixel.
    dxs, dys, fs : 1-D float64
        The gathered subset's offsets and reference values.
    gp : 1-D float32 or float64
        The deformed image sampled at the warped subset pixels.
    m : int
        Subset pixels.
    var_img : float
        Noise variance of one image (grey levels²).
    g0, dbuf : 1-D float64
        Work buffers (``g0`` receives ``g`` at the unwarped pixels).
    min_fraction : float
        ``z`` is left NaN where ``S / D`` is at most this.

    Returns
    -------
    (float, float)
        ``(S / D, z)``; NaN for flat subsets, ``(0, 0)`` when the warp is zero
        motion, ``(S / D, NaN)`` at or below ``min_fraction``.
    """
    if m < 3:
        return np.nan, np.nan
    mf = mg0 = mgp = 0.0
    for q in range(m):
        gz = np.float64(g[y0 + np.int64(dys[q]), x0 + np.int64(dxs[q])])
        g0[q] = gz
        mf += fs[q]
        mg0 += gz
        mgp += gp[q]
    return _evidence(fs, g0, gp, m, var_img, mf / m, mg0 / m, mgp / m, dbuf, min_fraction)


@nb.njit(**INLINE, fastmath=FASTMATH)
def _evidence(fs, g0, gp, m, var_img, mf, mg0, mgp, dbuf, min_fraction):
    """``(S / D, z)`` of one gathered subset (see :func:`zero_motion_evidence`;
    ``mf, mg0, mgp``: the three subsets' means)."""
    sf = s0 = sp = 0.0
    for q in range(m):
        sf += (fs[q] - mf) ** 2
        s0 += (g0[q] - mg0) ** 2
        sp += (gp[q] - mgp) ** 2
    if sf <= 0.0 or s0 <= 0.0 or sp <= 0.0:
        return np.nan, np.nan
    nf, n0, npp = 1.0 / math.sqrt(sf), 1.0 / math.sqrt(s0), 1.0 / math.sqrt(sp)
    # S and D first (a loop LLVM vectorises), the noise moments of S only
    # where S / D can flag the node
    evid = disc = 0.0
    for q in range(m):
        gph = (gp[q] - mgp) * npp
        d = (g0[q] - mg0) * n0 - gph
        e = (fs[q] - mf) * nf - gph
        dbuf[q] = d
        evid += max(2.0 * e * d - d * d, 0.0)
        disc += d * d
    if disc <= 0.0:
        return 0.0, 0.0
    if not evid > min_fraction * disc:
        return evid / disc, np.nan
    # noise of e per pixel, normalised like the subsets: both images' noise,
    # at least 1 % of the subset's contrast (noise-free images still round)
    s = math.sqrt(2.0 * (var_img + 1e-4 * sf / m)) * nf
    mean = var = 0.0
    for q in range(m):
        d = dbuf[q]
        a = 2.0 * abs(d) * s
        if a > 0.0:
            mu, m2 = _positive_part_moments(a, d * d)
            mean += mu
            var += m2 - mu * mu
    z = (evid - mean) / math.sqrt(var) if var > 0.0 else (np.inf if evid > mean else 0.0)
    return evid / disc, z


@nb.njit(**SERIAL_CALLEE, fastmath=FASTMATH)
def _lag_ncc(fz, mk, m, nf, f, top, left, box, sx, sy):
    """NCC of a reference subset (``fz``: its zero-mean values, 0 outside its
    mask ``mk``) with the reference shifted by ``(sx, sy)`` pixels; NaN when
    the shifted subset leaves the image or is flat.

    The subset's square is read row by row, contiguously and without a test
    per pixel (the bounding box ``box`` of its mask is tested once), so LLVM
    vectorises the three sums (issue 25: the kernel 2.2x faster than pixel by
    pixel with a test per pixel)."""
    rows, cols = f.shape
    r0, r1, c0, c1 = box
    y, x = top + sy, left + sx
    if y + r0 < 0 or x + c0 < 0 or y + r1 >= rows or x + c1 >= cols:
        return np.nan
    sg = sgg = sfg = 0.0
    for a in range(r0, r1 + 1):
        # row views indexed from 0 by the loop counter: no negative-index
        # wrap-around test per pixel, which keeps LLVM from vectorising
        gr = f[y + a, x + c0:x + c1 + 1]
        zr = fz[a, c0:c1 + 1]
        mr = mk[a, c0:c1 + 1]
        for b in range(gr.size):
            gv = np.float64(gr[b])
            sg += mr[b] * gv
            sgg += mr[b] * gv * gv
            sfg += zr[b] * gv
    vg = sgg - sg * sg / m
    if vg <= 0.0:
        return np.nan
    return sfg * nf / math.sqrt(vg)


@nb.njit(**INLINE, fastmath=FASTMATH)
def _dense_subset(f, x0, y0, h, sl, masks, fz, mk):
    """Fill ``fz`` with the node's zero-mean reference values (0 outside the
    mask component) and ``mk`` with the mask; returns the pixel count, the
    norm factor ``1 / sqrt(sum fz²)`` (0: fewer than 3 pixels or flat) and the
    mask's bounding box ``(r0, r1, c0, c1)`` in the square."""
    side = 2 * h + 1
    m = 0
    mf = 0.0
    r0 = c0 = side
    r1 = c1 = -1
    for a in range(side):
        for b in range(side):
            use = sl < 0 or masks[sl, a, b] != 0
            mk[a, b] = 1.0 if use else 0.0
            fz[a, b] = f[y0 - h + a, x0 - h + b] if use else 0.0
            if use:
                mf += fz[a, b]
                m += 1
                r0, r1, c0, c1 = min(r0, a), max(r1, a), min(c0, b), max(c1, b)
    if m < 3:
        return m, 0.0, (r0, r1, c0, c1)
    mf /= m
    sf = 0.0
    for a in range(side):
        for b in range(side):
            if mk[a, b] != 0.0:
                fz[a, b] -= mf
                sf += fz[a, b] ** 2
    return m, (1.0 / math.sqrt(sf) if sf > 0.0 else 0.0), (r0, r1, c0, c1)


@nb.njit(**SERIAL, fastmath=FASTMATH)
def lag_peaks(first, stop, f, nx, ny, slot, masks, h, cand, ncand, w, out):
    """The highest isolated secondary peak of the normalised autocorrelation
    of the reference subsets of nodes ``first`` to ``stop`` near candidate
    lags (serial: ``dic.threads.in_threads`` runs ranges side by side).

    Around each candidate lag ``c`` the NCC is evaluated on the
    ``(2w + 1)²`` lags ``c + [-w, w]²``; its maximum counts only when it lies
    inside that block (a local maximum, not the flank of the main lobe) and
    the NCC at the lag halfway to it is at most half the peak's (a second,
    separate peak, not a ridge along an edge).
    The peak value is refined by a parabola through its neighbours along x
    and along y.

    Parameters
    ----------
    f : (H, W) float32
        Reference image.
    nx, ny : (n,) int64
        Node pixels.
    slot, masks
        Mask slot per node (-1: full square) and the component masks.
    h : int
        Subset half-width.
    cand : (n, K, 2) int64
        Candidate lags ``(sx, sy)`` per node.
    ncand : (n,) int64
        Candidates used per node (0: the node is skipped).
    w : int
        Half-width of the lag block searched around a candidate.
    out : (n, 3) float64
        Receives ``(peak NCC, lag x, lag y)`` of the best isolated peak
        (``-inf`` and zeros when there is none).
    """
    side = 2 * h + 1
    nb_ = 2 * w + 1
    fz = np.empty((side, side))
    mk = np.empty((side, side))
    block = np.empty((nb_, nb_))
    for k in range(first, stop):
        out[k, 0] = -np.inf
        out[k, 1] = 0.0
        out[k, 2] = 0.0
        if ncand[k] == 0:
            continue
        x0, y0 = nx[k], ny[k]
        m, nf, box = _dense_subset(f, x0, y0, h, slot[k], masks, fz, mk)
        if nf == 0.0:
            continue
        for c in range(ncand[k]):
            _best_peak(fz, mk, m, nf, f, y0 - h, x0 - h, box, cand[k, c, 0], cand[k, c, 1],
                       w, block, out, k)


@nb.njit(**INLINE, fastmath=FASTMATH)
def _best_peak(fz, mk, m, nf, f, top, left, box, cx, cy, w, block, out, k):
    """Search the lag block around candidate ``(cx, cy)`` of node ``k`` and
    keep its peak in ``out[k]`` when isolated and higher (see :func:`lag_peaks`)."""
    best = -np.inf
    bi = bj = 0
    for i in range(2 * w + 1):
        for j in range(2 * w + 1):
            sx, sy = cx + j - w, cy + i - w
            v = -np.inf
            if sx != 0 or sy != 0:
                v = _lag_ncc(fz, mk, m, nf, f, top, left, box, sx, sy)
                if not v == v:  # NaN: out of the image or flat
                    v = -np.inf
            block[i, j] = v
            if v > best:
                best, bi, bj = v, i, j
    if bi == 0 or bj == 0 or bi == 2 * w or bj == 2 * w or not best > out[k, 0]:
        return
    sx, sy = cx + bj - w, cy + bi - w
    if abs(sx) < 2 and abs(sy) < 2:
        return  # next to zero lag: the main lobe
    mid = _lag_ncc(fz, mk, m, nf, f, top, left, box, int(round(0.5 * sx)),
                   int(round(0.5 * sy)))
    if not mid <= 0.5 * best:
        return  # no dip between zero lag and the peak: a ridge
    val = best
    for a0, a1, a2 in ((block[bi, bj - 1], best, block[bi, bj + 1]),
                       (block[bi - 1, bj], best, block[bi + 1, bj])):
        den = a0 - 2.0 * a1 + a2
        if den < 0.0 and a0 > -np.inf and a2 > -np.inf:
            val += -0.125 * (a2 - a0) ** 2 / den
    out[k, 0] = min(val, 1.0)
    out[k, 1] = sx
    out[k, 2] = sy
