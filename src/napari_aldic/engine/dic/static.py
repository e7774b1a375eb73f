"""Matches explained by grey levels that do not move with the material.

A subset match can converge, correlate at ZNCC 0.99 and predict a tiny
uncertainty, and still be wrong when part of what it matched does not move
with the material: an occluder, a dark bar, dust on the sensor, the black
edge of the field of view, or a texture that repeats within the search range.
Two tests flag such nodes after Local DIC (method in ``docs/method.md``,
section 6.5):

* **static features** (:data:`~napari_aldic.engine.Reason.STATIC_FEATURE`):
  part of the subset is explained better by zero motion than by the found
  warp. Per pixel the zero-normalised residual at zero motion minus that at
  the warp is compared (:func:`~napari_aldic.engine.kernels.static.static_evidence`):
  ``S``, the sum over the pixels that prefer zero motion, is set against
  ``D``, everything that tells the two explanations apart, and against what
  image noise alone gives (``z``, in standard deviations). A node is flagged
  when ``z > STATIC_Z`` and ``S / D > STATIC_FRACTION``. A subset that truly
  does not move (zero motion everywhere) has nothing to tell apart and is
  never flagged; one wholly on moving speckle leaves only noise in ``S``.
* **ambiguous matches** (:data:`~napari_aldic.engine.Reason.AMBIGUOUS_MATCH`):
  the reference subset's normalised autocorrelation has an isolated second
  peak within the search range nearly as high as the match itself
  (``>= AMBIGUITY`` times its ZNCC): a periodic texture, whose aliases
  match as well as the truth. Candidate lags come from the autocorrelation of
  image tiles (FFT), so speckle without repeats costs no per-node search.

References: the residual comparison is a likelihood-ratio test between two
motion hypotheses of each pixel (the zero-motion alternative is the one
static features impose), with the noise model of :mod:`.reliability`; the
peak test is the primary-to-secondary peak
ratio of PIV (R. D. Keane, R. J. Adrian, "Optimization of particle image
velocimeters", Meas. Sci. Technol. 1, 1990; J. Westerweel, "Fundamentals of
digital particle image velocimetry", Meas. Sci. Technol. 8, 1997), applied to
the reference's autocorrelation so that it judges the texture, not the
match.
"""

from __future__ import annotations

import numpy as np

from ..core.reasons import Reason
from ..kernels.static import lag_peaks, static_evidence

__all__ = ["STATIC_Z", "STATIC_FRACTION", "AMBIGUITY", "flag_static_features",
           "static_statistics", "ambiguity", "candidate_lags"]

#: evidence for zero motion beyond this many noise standard deviations ...
STATIC_Z = 20.0
#: ... and holding more than this share of what tells zero motion and the
#: found warp apart flags a node as matched on static features
STATIC_FRACTION = 0.01
#: a second autocorrelation peak at least this share of the match's ZNCC
#: makes the match ambiguous
AMBIGUITY = 0.8
#: tile autocorrelation peaks below this are not candidates at all
_CANDIDATE_MIN = 0.4
_CANDIDATES = 4  # per tile
_BLOCK = 2  # half-width of the lag block searched around a candidate


def static_statistics(im, grid, sub, p, active, image_var: float, half: int) -> np.ndarray:
    """``(S / D, z)`` per node (n, 2) of :func:`~..kernels.static.static_evidence`
    (NaN where not ``active``)."""
    out = np.empty((grid.n, 2))
    static_evidence(np.ascontiguousarray(im.f, np.float32),
                    np.ascontiguousarray(im.g, np.float32), im.g_spline.coef,
                    int(im.g_spline.order), grid.x.astype(np.int64), grid.y.astype(np.int64),
                    np.ascontiguousarray(p, np.float64), np.ascontiguousarray(active),
                    sub.slot.astype(np.int32), sub.masks, int(half), float(image_var), out)
    return out


def _tile_spans(size: int, tile: int) -> list[int]:
    """Starts of tiles of ``tile`` pixels covering ``size`` (the last one
    flush with the end)."""
    starts = list(range(0, max(size - tile, 0) + 1, tile))
    if starts[-1] + tile < size:
        starts.append(size - tile)
    return starts


def candidate_lags(f: np.ndarray, roi: np.ndarray, subset: int, reach: int):
    """Lags at which image tiles repeat: per tile up to ``_CANDIDATES``
    isolated local maxima of its normalised autocorrelation (at least
    ``_CANDIDATE_MIN``, ``2 <= |lag| <= reach`` along some axis).

    Returns ``(tile, ys, xs, lags)``: the tile size, tile starts along y and
    x, and ``lags[i][j]`` a (k, 2) int array of ``(sx, sy)`` for tile (i, j).
    """
    tile = max(64, 1 << int(np.ceil(np.log2(2 * subset))))
    th, tw = min(tile, f.shape[0]), min(tile, f.shape[1])
    reach = int(min(reach, th // 2, tw // 2))
    ys, xs = _tile_spans(f.shape[0], th), _tile_spans(f.shape[1], tw)
    shape = (2 * th, 2 * tw)
    lags = []
    for y0 in ys:
        m = roi[y0:y0 + th].astype(np.float64)
        t = np.asarray(f[y0:y0 + th], np.float64)
        row = []
        for x0 in xs:
            row.append(_tile_peaks(t[:, x0:x0 + tw], m[:, x0:x0 + tw], shape, reach))
        lags.append(row)
    return tile, np.asarray(ys), np.asarray(xs), lags


def _corr(a, b, shape):
    """Circular cross-correlation ``Σ a(x) b(x + s)`` of zero-padded tiles."""
    fa = np.fft.rfft2(a, shape)
    fb = np.fft.rfft2(b, shape)
    return np.fft.irfft2(np.conj(fa) * fb, shape)


def _tile_peaks(t, m, shape, reach: int) -> np.ndarray:
    """Candidate lags (k, 2) of one tile (``t`` grey values, ``m`` ROI)."""
    n = m.sum()
    if n < 0.25 * m.size:
        return np.zeros((0, 2), np.int64)
    t = (t - (t * m).sum() / n) * m
    t2 = t * t
    if t2.sum() <= 0:
        return np.zeros((0, 2), np.int64)
    num = _corr(t, t, shape)
    den = np.sqrt(np.maximum(_corr(t2, m, shape) * _corr(m, t2, shape), 0.0))
    over = _corr(m, m, shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.where((over >= 0.25 * m.size) & (den > 0), num / den, -np.inf)
    a = np.fft.fftshift(a)
    cy, cx = shape[0] // 2, shape[1] // 2
    a = a[cy - reach - 1:cy + reach + 2, cx - reach - 1:cx + reach + 2]
    core = a[1:-1, 1:-1]
    peak = core >= _CANDIDATE_MIN
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                peak &= core >= a[1 + dy:a.shape[0] - 1 + dy, 1 + dx:a.shape[1] - 1 + dx]
    sy, sx = np.nonzero(peak)
    sy, sx = sy - reach, sx - reach
    # one of each pair +-s (the autocorrelation is symmetric), off the main lobe
    keep = ((sy > 0) | ((sy == 0) & (sx > 0))) & (np.maximum(abs(sx), abs(sy)) >= 2)
    sy, sx = sy[keep], sx[keep]
    # the highest first, the shorter of (nearly) equal ones: a lattice's
    # primitive periods rather than their multiples
    order = np.argsort(-core[sy + reach, sx + reach] + 0.02 * np.hypot(sx, sy) / reach)
    order = order[:_CANDIDATES]
    return np.column_stack([sx[order], sy[order]]).astype(np.int64)


def ambiguity(im, roi, grid, sub, active, params) -> np.ndarray:
    """Per node (n,) the height of the highest isolated second peak of the
    reference subset's autocorrelation within ``params.search`` (``-inf``
    where there is none or the node is not ``active``)."""
    tile, ys, xs, lags = candidate_lags(im.f, roi, params.subset, params.search)
    h = params.half
    k_max = 8 * _CANDIDATES  # up to four tiles, each lag with both signs
    cand = np.zeros((grid.n, k_max, 2), np.int64)
    ncand = np.zeros(grid.n, np.int64)
    if not any(len(c) for row in lags for c in row):
        return np.full(grid.n, -np.inf)  # nothing repeats: no per-node search
    for k in np.nonzero(active)[0]:
        x, y = int(grid.x[k]), int(grid.y[k])
        iy = np.nonzero((ys <= y + h) & (ys + tile > y - h))[0]
        ix = np.nonzero((xs <= x + h) & (xs + tile > x - h))[0]
        found = [c for i in iy for j in ix for c in lags[i][j]]
        if found:
            # both signs: near the image border only one of them stays inside
            found = np.asarray(found)
            uniq = np.unique(np.concatenate([found, -found]), axis=0)[:k_max]
            cand[k, :len(uniq)] = uniq
            ncand[k] = len(uniq)
    out = np.empty((grid.n, 3))
    lag_peaks(np.ascontiguousarray(im.f, np.float32), grid.x.astype(np.int64),
              grid.y.astype(np.int64), sub.slot.astype(np.int32), sub.masks, int(h), cand,
              ncand, _BLOCK, out)
    return out[:, 0]


def flag_static_features(im, roi, grid, sub, p, zncc, reason, validity, params) -> np.ndarray:
    """``reason`` with trusted (or merely uncertain) nodes whose match static
    features explain flagged ``STATIC_FEATURE``, and those whose texture
    repeats within the search range ``AMBIGUOUS_MATCH``.

    Parameters
    ----------
    im : :class:`~.local.Images`
    roi : (H, W) bool
    grid, sub : the nodes and their subset masks.
    p : (n, 6) affine warps of the Local result.
    zncc, reason : (n,) of the Local result.
    validity : :class:`~.reliability.Validity` (its image noise).
    params : DICParams
    """
    reason = np.asarray(reason).copy()
    cand = (reason == Reason.OK) | (reason == Reason.UNCERTAIN)
    if not cand.any():
        return reason
    st = static_statistics(im, grid, sub, p, cand, validity.image_var, params.half)
    static = cand & (st[:, 1] > STATIC_Z) & (st[:, 0] > STATIC_FRACTION)
    peak = ambiguity(im, roi, grid, sub, cand & ~static, params)
    with np.errstate(invalid="ignore"):
        ambiguous = cand & ~static & (peak >= AMBIGUITY * np.minimum(zncc, 1.0))
    reason[static] = Reason.STATIC_FEATURE
    reason[ambiguous] = Reason.AMBIGUOUS_MATCH
    return reason
