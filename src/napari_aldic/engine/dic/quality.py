"""Measurement quality: speckle quality, predicted displacement noise, subset advice.

* **Speckle quality per node** -- the mean intensity gradient (MIG, mean of
  ``|∇f|`` over the subset) and the sum of squared subset intensity gradients
  (SSSIG, Pan et al. 2008: ``Σ f_x²`` and ``Σ f_y²`` over the subset; the
  smaller of the two limits the match).
* **Standard uncertainty of u, v per node** -- first-order propagation of
  white image noise (variance ``σ²`` in each image) through the subset's
  Gauss-Newton solution: ``Cov p = 2 σ² S⁻¹ H S⁻¹`` with ``H`` the full
  Gauss-Newton matrix of the subset shape function (6 x 6 affine, 12 x 12
  quadratic; the displacement gradients the subset also estimates take part
  of the information) and ``S = H - E`` its speckle part (``E``: the noise
  energy the spline derivative of the noisy reference adds). For ``σ²`` the
  node's own residual ``(1 - ZNCC) V`` is used, corrected for the B-spline
  interpolation of the deformed image at a sub-pixel position, which lowers
  the residual variance of its noise (by up to 30 % at half a pixel) but
  not the noise the match picks up (that lies at the speckle's low spatial
  frequencies, which interpolation passes). Pan's rule ``σ_u ≈ √2 σ / √SSSIG``
  is the translation-only, noise-free-gradient limit of this formula.
  For AL-DIC the smoothed field's uncertainty is this times a per-node
  smoothing gain from linear noise propagation through the ADMM run
  (:mod:`.uncertainty_aldic`).
* **Subset advice** -- the predicted standard uncertainty of a static
  (integer-shift) match for a range of subset sizes, from the reference
  image alone and its noise (Immerkær's estimator); the smallest subset at
  which a chosen fraction of the nodes meets the target.

References: B. Pan, H. Xie, Z. Wang, K. Qian, Z. Wang, "Study on subset size
selection in digital image correlation for speckle patterns", Optics Express
16(10), 7037-7048, 2008 (SSSIG); B. Pan, Z. Lu, H. Xie, "Mean intensity
gradient: an effective global parameter for quality assessment of the speckle
patterns used in digital image correlation", Optics and Lasers in Engineering
48(4), 469-477, 2010 (MIG); E. M. C. Jones, M. A. Iadicola (eds.), A Good
Practices Guide for Digital Image Correlation, iDICs, 2018 (noise floor).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from ..kernels.moments import HYPOT, ONES, centre_moments, moment_terms
from .covariance import covariance_diag, gather_matrices, mean_noise_factor
from .interpolation import (
    jacobian_smoothing,
    prefilter,
    reference_gradients,
    steepest_descent_gradients,
)
from .regularise import gradient_noise_gain
from .reliability import image_noise
from .window_moments import window_moments

__all__ = ["SpeckleQuality", "speckle_quality", "node_uncertainty", "static_uncertainty",
           "SubsetAdvice", "advise_subset", "interpolated_noise_factor", "SHAPE_TERMS"]

#: monomials (dx^p dy^q) of the subset shape function of each displacement
#: component: the affine one has 3, the quadratic one 6
SHAPE_TERMS = {"affine": ((0, 0), (1, 0), (0, 1)),
               "quadratic": ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))}


def _ones_moments(shape, x, y, half: int, order: int) -> np.ndarray:
    """(n, M) ``Σ (X - x)^p (Y - y)^q`` over each node's window clipped to the
    image (no ROI; ``(p, q)`` in ``moment_terms(order)`` order), from 1-D sums."""
    h, w = shape
    xi, yi = np.asarray(x, np.int64), np.asarray(y, np.int64)
    xs, ys = np.arange(w) - (w - 1) / 2.0, np.arange(h) - (h - 1) / 2.0
    c0, c1 = np.clip(xi - half, 0, w), np.clip(xi + half + 1, 0, w)
    r0, r1 = np.clip(yi - half, 0, h), np.clip(yi + half + 1, 0, h)
    cx, cy = np.zeros(w + 1), np.zeros(h + 1)
    cols = []
    for p, q in moment_terms(order):
        cx[1:] = np.cumsum(xs**p)
        cy[1:] = np.cumsum(ys**q)
        cols.append((cx[c1] - cx[c0]) * (cy[r1] - cy[r0]))
    return centre_moments(np.column_stack(cols), xi - (w - 1) / 2.0, yi - (h - 1) / 2.0,
                          order)


def _table(layout, terms, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Where the entries of a (2k, 2k) matrix sit in the moment arrays: block
    ``(i, j)`` is ``Σ a t tᵀ`` of the monomials ``terms``, ``a``'s centred
    moments (in ``moment_terms(order)`` order) starting at column ``c`` of
    array ``s`` for ``layout[i][j] = (s, c)`` (None: a zero block). Returns
    ``(src, col)`` as :func:`~.covariance.gather_matrices`
    takes them."""
    col = {pq: c for c, pq in enumerate(moment_terms(order))}
    k = len(terms)
    src = np.full((2 * k, 2 * k), -1, np.int64)
    cols = np.zeros((2 * k, 2 * k), np.int64)
    for bi in range(2):
        for bj in range(2):
            if layout[bi][bj] is None:
                continue
            arr, first = layout[bi][bj]
            for i, (p1, q1) in enumerate(terms):
                for j, (p2, q2) in enumerate(terms):
                    src[bi * k + i, bj * k + j] = arr
                    cols[bi * k + i, bj * k + j] = first + col[p1 + p2, q1 + q2]
    return src, cols


#: the matrices of a SpeckleQuality, in the order of their gather tables
MATRICES = ("hessian", "noise", "cross", "cross_noise")


@dataclass
class _NormalSums:
    """The window moments behind the matrices of :class:`SpeckleQuality`:
    entry ``(p, q)`` of matrix ``j`` (:data:`MATRICES`) is ``scale[j] *
    arrays[src[j, p, q]][:, col[j, p, q]]`` (``src < 0``: zero). Without
    smoothed steepest-descent images (``has_cross`` False) tables 2 and 3
    repeat 0 and 1."""

    arrays: tuple
    src: np.ndarray
    col: np.ndarray
    scale: np.ndarray
    has_cross: bool

    def matrix(self, j: int) -> np.ndarray | None:
        if j >= 2 and not self.has_cross:
            return None
        return gather_matrices(self.arrays, self.src[j], self.col[j], float(self.scale[j]))


class _Matrix:
    """A (n, 2k, 2k) matrix of :class:`SpeckleQuality`, gathered from the
    window moments on first use and then kept; it may be assigned (which
    :func:`_assigned_matrices` tells: the moments then no longer describe it)."""

    def __set_name__(self, owner, name):
        self.name = name

    def __get__(self, q, owner=None):
        if q is None:
            return self
        if self.name not in q.__dict__:
            q.__dict__[self.name] = q.sums.matrix(MATRICES.index(self.name))
        return q.__dict__[self.name]

    def __set__(self, q, value):
        q.__dict__[self.name] = value
        q.__dict__.setdefault("_assigned", set()).add(self.name)


def _assigned_matrices(q) -> set:
    """The matrices of ``q`` assigned by a caller (not gathered from its moments)."""
    return q.__dict__.get("_assigned", set())


@dataclass
class SpeckleQuality:
    """Speckle statistics of each node's reference subset.

    Attributes
    ----------
    mig : (n,) float
        Mean intensity gradient ``mean |∇f|`` (grey levels per pixel).
    sssig_x, sssig_y : (n,) float
        ``Σ f_x²`` and ``Σ f_y²`` over the subset (grey levels²).
    sssig : (n,) float
        ``min(sssig_x, sssig_y)``: the direction that limits the match.
    m : (n,) float
        Pixels of the subset inside the ROI.
    var_f : (n,) float
        Grey-level variance of the subset.
    sums : _NormalSums
        The window moments the matrices below are gathered from.
    hessian, noise : (n, 2k, 2k) float
        ``Σ J Jᵀ`` of the steepest-descent images ``J`` of the shape function
        and its expected noise part per unit noise variance (``E / σ²``).
    cross, cross_noise : (n, 2k, 2k) float or None
        ``Σ J ∇fᵀ`` (``J`` against the plain spline gradients) and its noise
        part per unit variance, when ``J`` is built from smoothed gradients;
        None: ``J`` is the plain gradient (``cross = hessian``).

    The four matrices are built on first access (the uncertainty is
    computed from the moments without them: at 4096², quadratic, they take
    1.2 GB); assigning one replaces it.
    """

    mig: np.ndarray
    sssig_x: np.ndarray
    sssig_y: np.ndarray
    m: np.ndarray
    var_f: np.ndarray
    sums: _NormalSums = field(repr=False)
    hessian = _Matrix()
    noise = _Matrix()
    cross = _Matrix()
    cross_noise = _Matrix()

    @property
    def sssig(self) -> np.ndarray:
        return np.minimum(self.sssig_x, self.sssig_y)


def _gradients(image: np.ndarray, order: int):
    """The spline gradients the IC-GN kernels use, and their noise gain."""
    gx, gy = reference_gradients(prefilter(image, order))
    # float32 as in correlate: one compiled specialisation of the moments kernel
    # (a float64 copy compiled it a second time, ~20 s on a first run)
    return (np.asarray(gx, np.float32), np.asarray(gy, np.float32),
            gradient_noise_gain(order))


@functools.lru_cache(maxsize=16)
def filter_gains(sigma: float, order: int) -> tuple[float, float, float]:
    """Noise gains of the x-derivatives of unit white noise: ``(g, g_J, c)`` =
    variance of the spline gradient, variance of the gradient after Gaussian
    smoothing of standard deviation ``sigma`` px (the steepest-descent images),
    and their covariance; from the impulse responses of the same filters."""
    n = 65
    delta = np.zeros((n, n))
    delta[n // 2, n // 2] = 1.0
    d = reference_gradients(prefilter(delta, order))[0].astype(np.float64)
    if sigma > 0:
        smooth = ndimage.gaussian_filter(delta, sigma, mode="reflect")
        dj = reference_gradients(prefilter(smooth, order))[0].astype(np.float64)
    else:
        dj = d
    return float(np.sum(d * d)), float(np.sum(dj * dj)), float(np.sum(d * dj))


def _subset_sums(img, gx, gy, jac, mask, x, y, half: int, deg: int):
    """Every window sum :func:`speckle_quality` needs, in one pass of the
    moment kernel (no product image is formed): the moments about the node
    up to ``deg`` of ``J Jᵀ`` (``J = jac`` or the gradients) and, when
    ``jac`` is given, ``J ∇fᵀ``; the sums of ``f``, ``f²``, ``|∇f|``,
    ``f_x²`` and ``f_y²`` (all within the ROI). Returns the moments side by
    side (n, F), the first column of each product's in it by name, and the
    moments of the ROI (n, M) (with a ROI: the columns named ``roi`` of the
    first)."""
    F, GX, GY, JX, JY = range(5)
    jx, jy = (GX, GY) if jac is None else (JX, JY)
    prods = {"jxjx": (jx, jx, deg), "jxjy": (jx, jy, deg), "jyjy": (jy, jy, deg),
             "f": (F, ONES, 0), "ff": (F, F, 0), "grad": (GX, GY, 0, HYPOT)}
    if jac is not None:
        prods.update(jxgx=(JX, GX, deg), jxgy=(JX, GY, deg), jygx=(JY, GX, deg),
                     jygy=(JY, GY, deg), gxgx=(GX, GX, 0), gygy=(GY, GY, 0))
    if mask is not None:
        prods["roi"] = (ONES, ONES, deg)
    images = [img, gx, gy] + ([] if jac is None else list(jac))
    flat = window_moments(images, list(prods.values()), x, y, half, mask=mask, centre=True,
                          joined=True)
    sizes = [(t[2] + 1) * (t[2] + 2) // 2 for t in prods.values()]
    start = dict(zip(prods, np.cumsum([0] + sizes[:-1]).tolist()))
    if jac is None:  # Σ f_x², Σ f_y²: moment (0, 0) of J Jᵀ
        start["gxgx"], start["gygy"] = start["jxjx"], start["jyjy"]
    if mask is None:
        roi = _ones_moments(img.shape, x, y, half, deg)
    else:
        roi = flat[:, start["roi"]:start["roi"] + len(moment_terms(deg))]
    return flat, start, roi


def speckle_quality(image, x, y, subset: int, roi=None, *, shape_function: str = "affine",
                    order: int = 3, gradients=None, jacobian=None) -> SpeckleQuality:
    """MIG, SSSIG and the Gauss-Newton matrix of the subsets centred at ``(x, y)``.

    Parameters
    ----------
    image : (H, W) array
        Reference image.
    x, y : (n,) int-like
        Node coordinates (pixels; column, row).
    subset : int
        Odd full subset width.
    roi : (H, W) bool, optional
        Pixels outside are left out of every subset.
    shape_function : {"affine", "quadratic"}
    order : {3, 5}
        B-spline order of the gradients (as the correlation uses).
    gradients : (gx, gy), optional
        The spline gradients of ``image`` of that order when already known.
    jacobian : (jx, jy, sigma), optional
        Gradients of the IC-GN steepest-descent images when they differ from
        ``gradients``: those of ``image`` smoothed by a Gaussian of standard
        deviation ``sigma`` px.
    """
    img = np.asarray(image)
    if not np.issubdtype(img.dtype, np.floating):
        img = img.astype(np.float64)  # float images are read as they are: no copy
    if img.ndim != 2:
        raise ValueError(f"speckle_quality needs a 2-D image, got shape {img.shape}")
    if subset < 3 or subset % 2 == 0:
        raise ValueError(f"subset must be an odd width >= 3, got {subset}")
    if shape_function not in SHAPE_TERMS:
        raise ValueError(f"shape_function must be one of {sorted(SHAPE_TERMS)}, "
                         f"got {shape_function!r}")
    whole = roi is None or bool(np.all(roi))
    mask = None if whole else np.asarray(roi, bool)
    if gradients is None:
        gx, gy, gain = _gradients(img, order)
    else:
        gx, gy = gradients
        gain = gradient_noise_gain(order)
    terms = SHAPE_TERMS[shape_function]
    deg = 2 * max(p + q for p, q in terms)
    flat, at, roi = _subset_sums(img, gx, gy, None if jacobian is None else jacobian[:2], mask,
                                 x, y, subset // 2, deg)
    # Σ ay ax t tᵀ = Σ ax ay t tᵀ: the lower-left block repeats the upper-right one;
    # the noise part is the window's pixel moments (of the ROI) times a gain
    hess = _table((((0, at["jxjx"]), (0, at["jxjy"])), ((0, at["jxjy"]), (0, at["jyjy"]))),
                  terms, deg)
    ones = (0, at["roi"]) if mask is not None else (1, 0)
    noise = _table(((ones, None), (None, ones)), terms, deg)
    if jacobian is None:
        tables, scales = [hess, noise, hess, noise], [1.0, gain, 1.0, gain]
    else:
        _, gain_j, gain_c = filter_gains(float(jacobian[2]), order)
        cross = _table((((0, at["jxgx"]), (0, at["jxgy"])), ((0, at["jygx"]), (0, at["jygy"]))),
                       terms, deg)
        tables, scales = [hess, noise, cross, noise], [1.0, gain_j, 1.0, gain_c]
    sums = _NormalSums((flat, flat if mask is not None else roi),
                       np.stack([t[0] for t in tables]), np.stack([t[1] for t in tables]),
                       np.array(scales), jacobian is not None)
    m = roi[:, 0]
    s1, s2, grad_abs, sx, sy = (flat[:, at[k]] for k in ("f", "ff", "grad", "gxgx", "gygy"))
    with np.errstate(invalid="ignore", divide="ignore"):
        mig = grad_abs / m
        var_f = np.maximum(s2 / m - (s1 / m) ** 2, 0.0)
    return SpeckleQuality(mig, sx, sy, m, var_f, sums)


def _covariance_diag(q: SpeckleQuality, var_e: np.ndarray) -> np.ndarray:
    """``diag(2 var_e M⁻¹ (A - E_J / 2) M⁻ᵀ)`` at the u and v entries, ``(n, 2)``
    px²: ``A = Σ J Jᵀ`` with noise part ``E_J``, ``M = Σ J ∇fᵀ`` less its noise
    part (for plain gradients ``M = S = H - E`` and the middle is ``S + E/2``;
    :func:`~.covariance.covariance_diag`). Straight from the window moments
    unless a matrix was assigned (one merely gathered from them, e.g. by
    AL-DIC's propagation, leaves them valid: 0.07-0.13 s saved at 15k nodes)."""
    sums = q.sums
    if sums is None or _assigned_matrices(q):
        a, ea = q.hessian, q.noise
        c, ec = (a, ea) if q.cross is None else (q.cross, q.cross_noise)
        n, size = a.shape[0], a.shape[1]
        flat = np.concatenate([np.reshape(v, (n, size * size)) for v in (a, ea, c, ec)],
                              axis=1).astype(np.float64)
        col = np.arange(4 * size * size).reshape(4, size, size)
        sums = _NormalSums((flat, flat), np.zeros_like(col), col, np.ones(4), True)
    arrays = tuple(np.asarray(v, np.float64) for v in sums.arrays)
    return covariance_diag(arrays, sums.src, sums.col, sums.scale, var_e, q.m)


@functools.lru_cache(maxsize=4)
def _interp_variance_table(order: int, n: int = 65) -> tuple[np.ndarray, np.ndarray]:
    """Variance of unit white noise interpolated by the cardinal B-spline of
    ``order`` at fractional offsets ``t`` in [0, 1] (1 at t = 0 and 1)."""
    delta = np.zeros(64)
    delta[32] = 1.0
    t = np.linspace(0.0, 1.0, n)
    rho = np.array([np.sum(ndimage.shift(delta, s, order=order, mode="grid-wrap") ** 2)
                    for s in t])
    return t, rho


def interpolated_noise_factor(u, v, order: int = 3) -> np.ndarray:
    """Variance of white noise of unit variance in the deformed image, after
    B-spline interpolation at the sub-pixel offsets ``(u mod 1, v mod 1)``:
    the product of the 1-D factors (1 at whole pixels, about 0.6-0.7 at half
    a pixel for cubic splines)."""
    u, v = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float))
    n = u.size
    return _mean_noise_factor(u.ravel(), v.ravel(), np.zeros((n, 4)), np.zeros(n), (0.0,),
                              order).reshape(u.shape)


def _mean_noise_factor(u, v, grad, half, offsets, order: int) -> np.ndarray:
    """:func:`interpolated_noise_factor` averaged over the grid ``offsets x
    offsets`` (times ``half`` px) of positions in each subset, the
    displacement moved there by the gradient ``grad`` (n, 4)."""
    t, rho = _interp_variance_table(int(order))
    return mean_noise_factor(u, v, grad, half, offsets, t, rho)


def node_uncertainty(q: SpeckleQuality, zncc, u, v, grad=None, order: int = 3) -> np.ndarray:
    """Standard uncertainty (px) of ``u`` and ``v`` per node, ``(n, 2)``.

    The noise variance of each image is estimated from the node's own
    residual: a correct match leaves ``(1 - ZNCC) V = (σ² + ρ σ²) / 2`` per
    pixel, where ``ρ`` (:func:`interpolated_noise_factor`) is what remains
    of the deformed image's noise after interpolation at the match's
    sub-pixel position -- averaged over the subset when the displacement
    gradient ``grad`` (n, 4) sweeps it across pixels. Then
    ``Cov = 2 σ² S⁻¹ H S⁻¹`` (module docstring). NaN where the node has no
    finite ZNCC or usable subset."""
    zncc = np.minimum(np.asarray(zncc, float), 1.0)
    u = np.asarray(u, float)
    v = np.asarray(v, float)
    if grad is None:
        rho = interpolated_noise_factor(u, v, order)
    else:
        h = np.sqrt(np.maximum(q.m, 1.0)) / 2  # about the subset half-width
        rho = _mean_noise_factor(u, v, np.nan_to_num(np.asarray(grad, float)), h,
                                 np.linspace(-1.0, 1.0, 5), order)
    var_e = 2.0 * (1.0 - zncc) * q.var_f / (1.0 + rho)
    var_e = np.where(np.isfinite(zncc), var_e, np.nan)
    with np.errstate(invalid="ignore"):  # degenerate (untrusted) nodes: NaN
        return np.sqrt(_covariance_diag(q, var_e))


def static_uncertainty(q: SpeckleQuality, noise: float) -> np.ndarray:
    """Standard uncertainty (px) of ``u``, ``v`` per node, ``(n, 2)``, of a
    whole-pixel match between two images with white noise of standard
    deviation ``noise`` (grey levels) each: ``Cov = 2 σ² S⁻¹ H S⁻¹``."""
    var = np.full(q.m.shape, float(noise) ** 2)
    return np.sqrt(_covariance_diag(q, var))


#: subset widths the advice tries when none are given
ADVICE_SUBSETS = (11, 15, 19, 21, 25, 31, 41, 51, 61, 81, 101)
#: the advice looks at a central window of at most this many pixels a side
ADVICE_WINDOW = 512


@dataclass
class SubsetAdvice:
    """Predicted displacement noise for a range of subset widths.

    Attributes
    ----------
    rows : list of dict
        Per subset: ``subset``, ``nodes``, ``median_std_px`` (median over
        nodes of the larger of the u, v standard uncertainties),
        ``p90_std_px`` and ``fraction`` (of nodes meeting the target).
    recommended : int or None
        Smallest subset where at least ``coverage`` of the nodes meet the
        target; None when no tried subset does.
    noise : float
        Image noise (grey levels, standard deviation) used.
    target : float
        Target standard uncertainty (px).
    coverage : float
    """

    rows: list
    recommended: int | None
    noise: float
    target: float
    coverage: float


def _advice_window(img: np.ndarray, mask: np.ndarray):
    """The central ``ADVICE_WINDOW`` square of the ROI's bounding box."""
    rows, cols = np.nonzero(mask)
    if rows.size == 0:
        raise ValueError("the ROI is empty: nothing to advise on")
    cy, cx = (rows.min() + rows.max()) // 2, (cols.min() + cols.max()) // 2
    half = ADVICE_WINDOW // 2
    r0 = max(0, min(cy - half, img.shape[0] - ADVICE_WINDOW))
    c0 = max(0, min(cx - half, img.shape[1] - ADVICE_WINDOW))
    sl = (slice(r0, r0 + ADVICE_WINDOW), slice(c0, c0 + ADVICE_WINDOW))
    return img[sl], mask[sl]


def advise_subset(image, roi=None, target_noise: float = 0.01, *, step: int | None = None,
                  subsets=None, noise: float | None = None, coverage: float = 0.9,
                  shape_function: str = "affine") -> SubsetAdvice:
    """The smallest subset whose predicted displacement noise meets a target.

    For each subset width the standard uncertainty of u and v of a static
    match (two images of the same speckle with white noise ``noise`` each)
    is predicted at nodes every ``step`` pixels from the reference image
    alone (:func:`static_uncertainty`); a node meets the target when the
    larger of the two is at most ``target_noise``. The analysis uses the
    central 512 x 512 pixels of the ROI's bounding box.

    Parameters
    ----------
    image : (H, W) array
        Reference image.
    roi : (H, W) bool, optional
    target_noise : float
        Target standard uncertainty of the displacement (px).
    step : int, optional
        Node spacing (default: half the smallest subset, at least 8).
    subsets : sequence of odd int, optional
        Widths to try (default :data:`ADVICE_SUBSETS`).
    noise : float, optional
        Image noise (grey levels); estimated from the image when None
        (Immerkær's estimator, :func:`~napari_aldic.engine.dic.reliability.image_noise`).
    coverage : float
        Fraction of nodes that must meet the target (0-1].
    """
    from ..core.images import as_gray_float, validate_roi
    from .mesh import make_grid

    img = as_gray_float(image, "reference image")
    mask = validate_roi(roi, img.shape)
    if not target_noise > 0:
        raise ValueError(f"target_noise must be > 0 px, got {target_noise}")
    if not 0 < coverage <= 1:
        raise ValueError(f"coverage must be in (0, 1], got {coverage}")
    widths = sorted(int(s) for s in (subsets or ADVICE_SUBSETS))
    if any(s < 3 or s % 2 == 0 for s in widths):
        raise ValueError(f"subsets must be odd widths >= 3, got {widths}")
    sigma = image_noise(img, mask) if noise is None else float(noise)
    img, mask = _advice_window(img, mask)
    step = int(step) if step else max(8, widths[0] // 2)
    gx, gy, _ = _gradients(img, 3)
    # as Local IC-GN matches: smoothed steepest-descent images
    j_sigma = jacobian_smoothing(img)
    jac = (*steepest_descent_gradients(img, 3, j_sigma), j_sigma)
    rows, best = [], None
    for s in widths:
        if s > min(img.shape):
            break
        grid = make_grid(mask, s, step)
        if grid.n == 0:
            continue
        q = speckle_quality(img, grid.x, grid.y, s, mask, shape_function=shape_function,
                            gradients=(gx, gy), jacobian=jac)
        worst = np.max(static_uncertainty(q, sigma), axis=1)
        worst = worst[np.isfinite(worst)]
        if worst.size == 0:
            continue
        frac = float(np.mean(worst <= target_noise))
        rows.append({"subset": s, "nodes": int(worst.size),
                     "median_std_px": float(np.median(worst)),
                     "p90_std_px": float(np.percentile(worst, 90)), "fraction": frac})
        if best is None and frac >= coverage:
            best = s
    if not rows:
        raise ValueError("no subset of the tried widths fits in the ROI")
    return SubsetAdvice(rows, best, sigma, float(target_noise), float(coverage))
