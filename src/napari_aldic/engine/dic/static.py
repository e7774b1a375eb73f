"""Matches explained by grey levels that do not move with the material.

A subset match can converge, correlate at ZNCC 0.99 and predict a tiny
uncertainty, and still be wrong when part of what it matched does not move
with the material: an occluder, a dark bar, dust on the sensor, the black
edge of the field of view, or a texture that repeats within the search range.
Three tests flag such nodes after Local DIC (method in ``docs/method.md``,
section 6.5; the edge test is described at :func:`static_edges`):

* **static features** (:data:`~napari_aldic.engine.Reason.STATIC_FEATURE`):
  part of the subset is explained better by zero motion than by the found
  warp. Per pixel the zero-normalised residual at zero motion minus that at
  the warp is compared
  (:func:`~napari_aldic.engine.kernels.static.zero_motion_evidence`, computed
  by affine IC-GN at each converged node from the samples of its last step,
  so the test costs no second pass over the subsets):
  ``S``, the sum over the pixels that prefer zero motion, is set against
  ``D``, everything that tells the two explanations apart, and against what
  image noise alone gives (``z``, in standard deviations). A node is flagged
  when ``z > STATIC_Z`` and ``S / D > STATIC_FRACTION``. A subset that truly
  does not move (zero motion everywhere) has nothing to tell apart and is
  never flagged; one wholly on moving speckle leaves only noise in ``S``.
* **static edges** (also ``STATIC_FEATURE``): a subset with a flat region
  (a bar, an occluder) is refitted without it; a match that moves when the
  flat region's edge no longer holds it leaned on a static edge.
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
from scipy import fft as sp_fft, ndimage as ndi
from scipy.spatial import cKDTree

from ..core.files import array_digest
from ..core.reasons import Reason
from ..kernels.static import lag_peaks
from ..kernels.sums import window_sums
from .icgn import icgn_solve
from .subsets import integral_image, rect_sums
from .threads import in_threads

__all__ = ["STATIC_Z", "STATIC_FRACTION", "STATIC_MIN_MOTION", "AMBIGUITY", "flag_static_features",
           "ambiguity", "candidate_lags", "prefetch_static"]

#: evidence for zero motion beyond this many noise standard deviations ...
STATIC_Z = 20.0
#: ... and holding more than this share of what tells zero motion and the
#: found warp apart flags a node as matched on static features
STATIC_FRACTION = 0.01
#: nodes whose match moved them less than this (px) are not tested for
#: static features
STATIC_MIN_MOTION = 0.5
#: a second autocorrelation peak at least this share of the match's ZNCC
#: makes the match ambiguous
AMBIGUITY = 0.8
#: tile autocorrelation peaks below this are not candidates at all
_CANDIDATE_MIN = 0.4
_CANDIDATES = 4  # per tile
_BLOCK = 2  # half-width of the lag block searched around a candidate
#: a pixel is flat when the grey-level standard deviation of its
#: FLAT_WINDOW² neighbourhood, in both images, is at most FLAT_NOISE times
#: the image noise plus FLAT_GL (a bar, an occluder, a saturated or black
#: field of view; 5 x 5 windows and twice the noise found "flat" pixels in
#: 2 px speckle at 10 GL, a third of whose nodes the test then rejected)
FLAT_WINDOW = 9
FLAT_NOISE = 1.5
FLAT_GL = 0.5
#: a flat window's standard deviation is at most this share of the image's
#: typical (75th percentile) local standard deviation
FLAT_CONTRAST = 0.5
#: pixels this close (px) to a flat region are left out of the edge test's
#: refit: the region's edge, which the spline gradients spread over a few
#: pixels, is what may not move (2 px kept the false strain: the first
#: speckle rows beside a bar still pinned the refit)
FLAT_MARGIN = 3
#: nodes whose subset is at least this share flat get the edge test ...
EDGE_SHARE = 0.05
#: ... and are flagged when the refit without the flat region moves the node
#: by more than EDGE_SIGMAS predicted standard deviations (of the pixels
#: refitted) and EDGE_MIN px, or when less than EDGE_KEEP of the subset is
#: left to refit (its match rests on the flat region's edge: quadratic
#: subsets centred in a horizontal bar, 22 nodes, converge off the truth)
EDGE_SIGMAS = 6.0
EDGE_MIN = 0.05
EDGE_KEEP = 0.3
#: flat pixels per node below which their windows' counts come from the
#: pixels' positions rather than a summed-area table (:func:`_window_counts`)
SPARSE_FLAT = 0.1


def _tile_spans(size: int, tile: int) -> np.ndarray:
    """Starts of tiles of ``tile`` pixels covering ``size`` (the last one
    flush with the end)."""
    starts = list(range(0, max(size - tile, 0) + 1, tile))
    if starts[-1] + tile < size:
        starts.append(size - tile)
    return np.asarray(starts)


def candidate_lags(f: np.ndarray, roi: np.ndarray, subset: int, reach: int):
    """Lags at which image tiles repeat: per tile up to ``_CANDIDATES``
    isolated local maxima of its normalised autocorrelation (at least
    ``_CANDIDATE_MIN``, ``2 <= |lag| <= reach`` along some axis).

    Returns ``(tile, ys, xs, lags)``: the tile size, tile starts along y and
    x, and ``lags`` (len(ys), len(xs), _CANDIDATES, 2) int64 of ``(sx, sy)``
    per tile, padded with ``(0, 0)`` (no candidate).
    """
    tile = max(64, 1 << int(np.ceil(np.log2(2 * subset))))
    th, tw = min(tile, f.shape[0]), min(tile, f.shape[1])
    reach = int(min(reach, th // 2, tw // 2))
    ys, xs = _tile_spans(f.shape[0], th), _tile_spans(f.shape[1], tw)
    # every tile at once: one batched FFT per correlation instead of a
    # Python loop of small ones
    def tiles(a, dtype):
        view = np.lib.stride_tricks.sliding_window_view(np.asarray(a), (th, tw))
        return view[ys[:, None], xs[None, :]].reshape(-1, th, tw).astype(dtype)
    t = tiles(f, np.float64)
    m = tiles(roi, np.float64)
    a = _normalised_autocorrelation(t, m, reach)
    lags = _tile_peaks(a, reach).reshape(len(ys), len(xs), _CANDIDATES, 2)
    return tile, ys, xs, lags


def _normalised_autocorrelation(t, m, reach):
    """(T, 2 reach + 3, 2 reach + 3) normalised autocorrelation of each tile
    (grey values ``t``, ROI ``m``) at lags ``[-reach - 1, reach + 1]²``; -inf
    where the overlap is under a quarter of the tile or the tile is mostly
    outside the ROI."""
    th, tw = t.shape[1:]
    size = th * tw
    n = m.sum(axis=(1, 2))
    mean = np.where(n > 0, (t * m).sum(axis=(1, 2)) / np.maximum(n, 1), 0.0)
    t = (t - mean[:, None, None]) * m
    t2 = t * t
    # the FFTs need only cover the lags searched (linear, not circular,
    # correlation up to reach + 1), not twice the tile
    shape = tuple(sp_fft.next_fast_len(d + reach + 2, real=True) for d in (th, tw))
    lag = np.arange(-reach - 1, reach + 2)
    iy, ix = np.ix_(lag % shape[0], lag % shape[1])

    # the autocorrelation in single precision (half the time: it is compared
    # with _CANDIDATE_MIN = 0.4 and between lags 1e-3 apart, its rounding is
    # ~1e-6 of the tile's energy); the ROI's overlaps stay exact counts
    def corr(fa, fb):  # Σ a(x) b(x + s) at the lags searched
        return sp_fft.irfft2(np.conj(fa) * fb, shape, workers=-1)[:, iy, ix].astype(np.float64)

    def spectrum(a, dtype=np.float32):
        return sp_fft.rfft2(a.astype(dtype, copy=False), shape, workers=-1)
    ft = spectrum(t)
    num = corr(ft, ft)
    full = m.all(axis=(1, 2))
    # Σ t²(x) m(x + s) and Σ m(x) t²(x + s): over a whole tile, sums of t² on
    # the overlap rectangles (an integral image) ...
    ii = np.zeros((len(t), th + 1, tw + 1))
    ii[:, 1:, 1:] = t2.cumsum(axis=1).cumsum(axis=2)
    sy, sx = np.meshgrid(lag, lag, indexing="ij")

    def rect(y0, y1, x0, x1):
        return ii[:, y1, x1] - ii[:, y0, x1] - ii[:, y1, x0] + ii[:, y0, x0]
    lo_y, hi_y = np.maximum(0, -sy), th - np.maximum(0, sy)
    lo_x, hi_x = np.maximum(0, -sx), tw - np.maximum(0, sx)
    c_t2m = rect(lo_y, hi_y, lo_x, hi_x)
    c_mt2 = rect(lo_y + sy, hi_y + sy, lo_x + sx, hi_x + sx)
    over = np.broadcast_to(((th - abs(sy)) * (tw - abs(sx))).astype(float), num.shape).copy()
    part = np.nonzero(~full)[0]
    if part.size:  # ... and, where the ROI cuts a tile, FFTs of the mask
        ft2 = spectrum(t2[part], np.float64)
        fm = spectrum(m[part], np.float64)
        c_t2m[part] = corr(ft2, fm)
        c_mt2[part] = corr(fm, ft2)
        over[part] = corr(fm, fm)
    den = np.sqrt(np.maximum(c_t2m * c_mt2, 0.0))
    ok = ((over >= 0.25 * size) & (den > 0) & (n >= 0.25 * size)[:, None, None]
          & ((t2.sum(axis=(1, 2)) > 0)[:, None, None]))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(ok, num / den, -np.inf)


def _tile_peaks(a, reach: int) -> np.ndarray:
    """Candidate lags (T, _CANDIDATES, 2) of the tiles' autocorrelations
    ``a`` (from :func:`_normalised_autocorrelation`), padded with zeros."""
    core = a[:, 1:-1, 1:-1]
    peak = core >= _CANDIDATE_MIN
    ny, nx = a.shape[1], a.shape[2]
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                peak &= core >= a[:, 1 + dy:ny - 1 + dy, 1 + dx:nx - 1 + dx]
    sy, sx = np.mgrid[-reach:reach + 1, -reach:reach + 1]
    # one of each pair +-s (the autocorrelation is symmetric), off the main lobe
    peak &= (((sy > 0) | ((sy == 0) & (sx > 0))) & (np.maximum(abs(sx), abs(sy)) >= 2))[None]
    # the highest first, the shorter of (nearly) equal ones: a lattice's
    # primitive periods rather than their multiples
    score = np.where(peak, -core + 0.02 * np.hypot(sx, sy)[None] / reach, np.inf)
    flat = score.reshape(len(a), -1)
    order = np.argsort(flat, axis=1, kind="stable")[:, :_CANDIDATES]
    keep = np.isfinite(np.take_along_axis(flat, order, axis=1))
    lags = np.stack([sx.ravel()[order], sy.ravel()[order]], axis=2)
    return np.where(keep[:, :, None], lags, 0).astype(np.int64)


def _node_candidates(grid, tile, ys, xs, lags, active, h):
    """(n, K, 2) candidate lags of each node (both signs of every lag of the
    tiles its subset overlaps: near the image border only one of them stays
    inside) and their number (n,); ``(0, 0)`` entries are padding."""
    def overlaps(starts, c):
        # at most three tiles along one axis (the last tile, flush with the
        # image's end, overlaps the one before it)
        lo = np.searchsorted(starts + tile, c - h, side="right")
        hi = np.searchsorted(starts, c + h, side="right") - 1
        return [(np.clip(lo + i, 0, len(starts) - 1), lo + i <= hi) for i in range(3)]
    cand = []
    for iy, oky in overlaps(ys, grid.y):
        for ix, okx in overlaps(xs, grid.x):
            c = np.where((oky & okx & active)[:, None, None], lags[iy, ix], 0)
            cand += [c, -c]
    cand = np.concatenate(cand, axis=1)
    # real lags first (the kernel reads the first ncand); duplicates are kept
    # (searching a lag twice finds the same peak)
    real = np.any(cand != 0, axis=2)
    ncand = real.sum(axis=1).astype(np.int64)
    order = np.argsort(~real, axis=1, kind="stable")[:, :max(int(ncand.max()), 1)]
    return np.ascontiguousarray(np.take_along_axis(cand, order[:, :, None], axis=1)), ncand


def _lags_key(roi, params) -> tuple:
    return ("lags", array_digest(roi), params.subset, params.search)


def _peaks_key(roi, grid, sub, params) -> tuple:
    return ("peaks", *_lags_key(roi, params)[1:], array_digest(grid.x), array_digest(grid.y),
            array_digest(sub.slot), array_digest(sub.masks), array_digest(sub.reason))


def prefetch_static(im, roi, grid, sub, params) -> None:
    """Start the tests' work on the reference alone on ``im``'s background
    thread (the deformed image's: :func:`prefetch_static_deformed`): the
    flat-pixel windows of ``f``, and the tiles' candidate lags with the
    autocorrelation peaks of every usable node's subset (:func:`ambiguity`
    then reads those of the nodes it tests)."""
    im.prefetch(("flat_var",), lambda: _window_var(im.f))
    im.prefetch(_peaks_key(roi, grid, sub, params),
                lambda: _peak_heights(im, roi, grid, sub, sub.reason == Reason.OK, params,
                                      serial=True))


def prefetch_static_deformed(im) -> None:
    """Start the flat-pixel windows of the deformed image on ``im``'s
    background thread, never kept for the next pair. Queued after the jobs
    the analysis needs more (the reference's, the quality's): if the thread
    has not started it when the tests need it, it is computed there (0.024 s
    at 1024²); queued before them, it made those late (a speckle job computed
    twice in 2 runs of 6)."""
    im.prefetch(("flat_var_g",), lambda: _window_var(im.g), keep=False)


def _peak_heights(im, roi, grid, sub, active, params, serial: bool = False) -> np.ndarray:
    """:func:`ambiguity` at the ``active`` nodes (``serial``: on this thread
    only, for the background one)."""
    tile, ys, xs, lags = im.memo(_lags_key(roi, params),
                                 lambda: candidate_lags(im.f, roi, params.subset, params.search))
    if not lags.any():
        return np.full(grid.n, -np.inf)  # nothing repeats: no per-node search
    cand, ncand = _node_candidates(grid, tile, ys, xs, lags, np.asarray(active), params.half)
    out = np.empty((grid.n, 3))
    args = (np.ascontiguousarray(im.f, np.float32), grid.x.astype(np.int64),
            grid.y.astype(np.int64), sub.slot.astype(np.int32), sub.masks, int(params.half),
            cand, ncand, _BLOCK, out)
    if serial:
        lag_peaks(0, grid.n, *args)
    else:
        in_threads(lag_peaks, grid.n, *args, grain=64)
    return out[:, 0]


def ambiguity(im, roi, grid, sub, active, params) -> np.ndarray:
    """Per node (n,) the height of the highest isolated second peak of the
    reference subset's autocorrelation within ``params.search`` (``-inf``
    where there is none or the node is not ``active``; ``active`` nodes are
    usable ones). Each node's peak is its own reference subset's: those of
    every usable node, started ahead (:func:`prefetch_static`) or kept for
    the next pair with this reference, serve any ``active`` set."""
    key = _peaks_key(roi, grid, sub, params)
    if key in im.pending or im.ref_cache is not None:
        usable = sub.reason == Reason.OK
        peaks = im.memo(key, lambda: _peak_heights(im, roi, grid, sub, usable, params))
        return np.where(np.asarray(active) & usable, peaks, -np.inf)
    return _peak_heights(im, roi, grid, sub, active, params)


def _window_var(a: np.ndarray, tile: int = 120) -> np.ndarray:
    """Grey-level variance of every pixel's FLAT_WINDOW² window (float64;
    mirrored at the image's border, as ``ndimage.uniform_filter`` sees it).

    The summed-area tables of the reference window sums
    (:func:`~napari_aldic.engine.kernels.sums.window_sums`, parallel) over
    overlapping square tiles: float64 sums, a third of the time of two
    uniform filters."""
    r = FLAT_WINDOW // 2
    h, w = a.shape
    ny, nx = -(-h // tile), -(-w // tile)
    pad = np.pad(np.asarray(a, np.float32), ((r, r + ny * tile - h), (r, r + nx * tile - w)),
                 mode="symmetric")
    side = tile + FLAT_WINDOW - 1
    tiles = np.lib.stride_tricks.sliding_window_view(pad, (side, side))[::tile, ::tile]
    # a writable copy: a read-only view (one tile) would compile a second specialisation
    s1, s2 = window_sums(np.array(tiles.reshape(-1, side, side), order="C"), FLAT_WINDOW)
    s1 *= 1.0 / FLAT_WINDOW ** 2
    s2 *= 1.0 / FLAT_WINDOW ** 2
    s1 *= s1
    s2 -= s1
    var = s2.reshape(ny, nx, tile, tile).transpose(0, 2, 1, 3)
    return var.reshape(ny * tile, nx * tile)[:h, :w]


def _flat_pixels(f, g, roi, image_var: float, f_var=None, g_var=None) -> np.ndarray:
    """Pixels of the ROI flat in both images: their window's variance is that
    of the noise (:data:`FLAT_NOISE`) and well below the image's typical
    local contrast (:data:`FLAT_CONTRAST` of the 75th percentile). The second
    condition keeps speckle under heavy noise (whose windows are not much
    above the noise either) from counting as flat: a static region stands
    out from the speckle around it, noise does not. ``f_var``, ``g_var``:
    callables that return the windows' variance of ``f`` and ``g``
    (:func:`_window_var`; default: computed here), called only when needed."""
    thr2 = (FLAT_NOISE * np.sqrt(image_var) + FLAT_GL) ** 2
    roi = np.asarray(roi, bool)
    whole = roi.all()
    flat = roi.copy()
    for a, var in ((f, f_var), (g, g_var)):
        if not flat.any():  # speckle: the reference alone shows nothing flat
            break
        var = _window_var(a) if var is None else var()
        flat &= var <= thr2
        if flat.any() and not _typical_at_least(var, roi, whole, thr2 / FLAT_CONTRAST ** 2):
            typical = np.percentile(var if whole else var[roi], 75)
            flat &= var <= FLAT_CONTRAST ** 2 * typical
    return flat


def _typical_at_least(var, roi, whole: bool, bound: float) -> bool:
    """Whether the 75th percentile of ``var`` over the ROI is at least
    ``bound`` (then the contrast condition of :func:`_flat_pixels` follows
    from the noise one): counted, not sorted."""
    v = var if whole else var[roi]
    # np.percentile's 75th interpolates the sorted values at j and j + 1
    return np.count_nonzero(v < bound) <= int(np.floor(0.75 * (v.size - 1)))


def _window_counts(flat: np.ndarray, x: np.ndarray, y: np.ndarray, h: int) -> np.ndarray:
    """Pixels of ``flat`` in each node's ``(2h + 1)²`` window (inside the
    image). On speckle only noise makes a pixel flat (~100 of a megapixel):
    each of those then finds the nodes whose windows hold it (a k-d tree of
    the nodes, ~1 ms), instead of an image-sized summed-area table (~15 ms)."""
    fy, fx = np.nonzero(flat)
    if fy.size > SPARSE_FLAT * x.size:
        return rect_sums(integral_image(flat), x - h, y - h, x + h, y + h)
    if fy.size == 0:
        return np.zeros(x.size, np.int64)
    tree = cKDTree(np.column_stack([x, y]))
    # integer positions: Chebyshev distance <= h + 0.5 is the window exactly
    hits = tree.query_ball_point(np.column_stack([fx, fy]), r=h + 0.5, p=np.inf)
    return np.bincount(np.concatenate([np.asarray(j, np.int64) for j in hits]),
                       minlength=x.size)


def static_edges(im, roi, grid, sub, p, cand, image_var: float, std, params) -> np.ndarray:
    """``cand`` nodes whose match leans on the edge of a flat region that
    does not move with the rest of the subset.

    A subset that straddles a static bar or occluder can bend its affine warp
    so that the bar's edge stays put and the speckle beside it moves part of
    the way (a false strain dv/dy of -0.05 next to a 16 px bar): the
    zero-motion test sees no pixel that prefers zero motion, but the node is
    off by 0.5 px. Each subset with at least :data:`EDGE_SHARE` flat pixels
    is refitted (affine IC-GN from its match) without them and a margin of
    :data:`FLAT_MARGIN` px: a flat region that moves with the material (a
    saturated spot) leaves the match where it was, a static one does not.

    Parameters
    ----------
    im : :class:`~.images.Images`
    roi : (H, W) bool
    grid, sub : the nodes and their subset masks.
    p : (n, 6) affine warps of the Local result.
    cand : (n,) bool nodes to test.
    image_var : noise variance of one image (grey levels²).
    std : (n,) predicted standard uncertainty (px) of the nodes' displacement.
    params : DICParams

    Returns
    -------
    (n,) bool
    """
    out = np.zeros(grid.n, bool)
    h, size = params.half, params.subset
    flat = _flat_pixels(im.f, im.g, roi, image_var,
                        lambda: im.memo(("flat_var",), lambda: _window_var(im.f)),
                        lambda: im.memo(("flat_var_g",), lambda: _window_var(im.g), keep=False))
    if not flat.any():
        return out
    x, y = grid.x.astype(np.int64), grid.y.astype(np.int64)
    share = _window_counts(flat, x, y, h) / (size * size)
    nodes = np.nonzero(cand & (share >= EDGE_SHARE))[0]
    if nodes.size == 0:
        return out
    # the flatness window erodes the region by its half-width: grow it back too
    near = ndi.binary_dilation(flat, iterations=FLAT_MARGIN + FLAT_WINDOW // 2)
    masks = np.empty((nodes.size, size, size), np.uint8)
    for i, k in enumerate(nodes):
        own = sub.masks[sub.slot[k]] if sub.slot[k] >= 0 else 1
        masks[i] = own & ~near[y[k] - h:y[k] + h + 1, x[k] - h:x[k] + h + 1]
    own_px = np.where(sub.slot[nodes] >= 0, sub.fraction[nodes], 1.0) * size * size
    kept = masks.sum(axis=(1, 2))
    few = kept < EDGE_KEEP * own_px
    jgx, jgy = (im.fgx, im.fgy) if im.jgx is None else (im.jgx, im.jgy)
    rp, _, _, rr = icgn_solve(im.f, jgx, jgy, im.g_spline, x[nodes], y[nodes], p[nodes],
                              ~few, np.arange(nodes.size, dtype=np.int32), masks, h,
                              params.max_iter, params.tol, lin=(im.fgx, im.fgy))
    moved = np.hypot(rp[:, 0] - p[nodes, 0], rp[:, 3] - p[nodes, 3])
    # the refit's noise grows as fewer pixels are left
    limit = np.maximum(EDGE_MIN, EDGE_SIGMAS * std[nodes] * np.sqrt(own_px / np.maximum(kept, 1)))
    with np.errstate(invalid="ignore"):
        agree = (rr == Reason.OK) & ~(moved > limit)
    out[nodes] = few | ~agree
    return out


def flag_static_features(im, roi, grid, sub, p, zncc, reason, evidence, validity,
                         params) -> np.ndarray:
    """``reason`` with trusted (or merely uncertain) nodes whose match static
    features explain flagged ``STATIC_FEATURE``, and those whose texture
    repeats within the search range ``AMBIGUOUS_MATCH``.

    Parameters
    ----------
    im : :class:`~.images.Images`
    roi : (H, W) bool
    grid, sub : the nodes and their subset masks.
    p : (n, 6) affine warps of the Local result.
    zncc, reason : (n,) of the Local result.
    evidence : (n, 2) zero-motion evidence ``(S / D, z)`` of the Local
        result (:func:`~.local.solve_local`; NaN where not tested).
    validity : :class:`~.reliability.Validity` (image noise, predicted
        uncertainty).
    params : DICParams
    """
    reason = np.asarray(reason).copy()
    cand = (reason == Reason.OK) | (reason == Reason.UNCERTAIN)
    if not cand.any():
        return reason
    # zero motion is an alternative worth testing only where the match moved
    # the subset clearly: closer to it, pixels where the shape function does
    # not follow the field (a 0.5 px wave) prefer it without any static
    # feature (203 of 665 nodes at 1 GL), and a static feature's pull would
    # move the node by less than STATIC_MIN_MOTION
    moved = cand & (np.hypot(p[:, 0], p[:, 3]) >= STATIC_MIN_MOTION)
    # second-order subsets are not tested (IC-GN computes no evidence for
    # them): warping each subset with the affine part of its match only, the
    # missing curvature reads as evidence for zero motion (a 36 px wave: 132
    # of 665 nodes)
    with np.errstate(invalid="ignore"):
        static = moved & (evidence[:, 1] > STATIC_Z) & (evidence[:, 0] > STATIC_FRACTION)
    std = np.max(validity.std(zncc), axis=1)
    # whatever the motion: a node matched as static beside a flat region whose
    # speckle moves is caught too (quadratic subsets on a vertical bar: four
    # nodes on its edge at u = 0.1 px, the truth 1.3 px)
    static |= static_edges(im, roi, grid, sub, p, cand & ~static, validity.image_var, std,
                           params)
    peak = ambiguity(im, roi, grid, sub, cand & ~static, params)
    with np.errstate(invalid="ignore"):
        ambiguous = cand & ~static & (peak >= AMBIGUITY * np.minimum(zncc, 1.0))
    reason[static] = Reason.STATIC_FEATURE
    reason[ambiguous] = Reason.AMBIGUOUS_MATCH
    return reason
