"""Validity tests: is a converged subset match the right one, and how sure is it?

IC-GN converges to *a* local optimum of the correlation criterion; whether it
is the right one has to be judged from the data. The tests here (their
thresholds and measured effect are in ``docs/method.md``, section 6):

* **image noise** -- the standard deviation of white noise in each image,
  estimated from the images alone (Immerkær's Laplacian-difference
  operator, which speckle of a few pixels barely excites);
* **match quality, absolute and relative** -- a correct match of a subset
  with grey-level variance ``V`` leaves a residual per pixel about equal to
  the image noise, ``(1 - ZNCC) V ≈ σ²``. The reference ``σ̂²`` is the median
  residual of the converged nodes, but never more than twice the image noise
  seen in the images: when most matches are wrong (motion beyond the search
  range, unrelated images) their median is no reference. A node is a poor
  match when ``1 - ZNCC > 0.1 + zncc_rel σ̂² / V``: 0.1 allows model
  mismatch (lighting, out-of-plane motion, strain gradients), the second term
  the noise. A clean image then rejects a ZNCC of 0.85, a correct match at
  50 grey levels of noise (ZNCC ≈ 0.6) is not rejected for its ZNCC;
* **standard uncertainty** of ``u, v`` from the Gauss-Newton matrix of the
  subset and its own residual (noise in both images, the noise carried by
  the reference gradients removed), ``Var u ≈ 2 σ_e² [S⁻¹ H S⁻¹]_uu``;
  a node whose uncertainty exceeds ``max_uncertainty`` is flagged;
* **AL-DIC global mismatch** -- the subset must match the global field's warp
  nearly as well as its own local match: the drop of ZNCC is converted to
  the misfit it implies (:meth:`Validity.misfit`) and compared with
  ``GLOBAL_TOLERANCE`` plus ``GLOBAL_SIGMAS`` standard uncertainties.

References: J. Immerkær, "Fast noise variance estimation", Computer Vision and
Image Understanding 64(2), 1996; B. Pan, "Reliability-guided digital image
correlation for image deformation measurement", Applied Optics 48(8), 2009;
E. M. C. Jones, M. A. Iadicola (eds.), A Good Practices Guide for Digital
Image Correlation, iDICs, 2018 (noise floor, match-quality checks).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..core.params import DICParams
from ..kernels.subset import subset_stats
from .subsets import check_masks

__all__ = ["SubsetStats", "subset_statistics", "image_noise", "displacement_variance",
           "Validity", "MISMATCH_ALLOWANCE", "NOISE_CAP", "GLOBAL_TOLERANCE", "GLOBAL_SIGMAS"]

#: 1 - ZNCC a correct match may lose to what the affine, grey-level-affine
#: model does not describe (lighting, out-of-plane motion, strain gradients);
#: spurious matches of 31 px speckle subsets reach at most ZNCC ~0.85
MISMATCH_ALLOWANCE = 0.1
#: the reference residual of a correct match is at most this many times the
#: image noise variance measured in the images
NOISE_CAP = 2.0
#: AL-DIC: how far (px, as a misfit of the subset) the global field may
#: depart from a node's own match beyond noise, and how many standard
#: uncertainties of that match the noise may take
GLOBAL_TOLERANCE = 0.2
GLOBAL_SIGMAS = 4.0
# Immerkær's mask [[1,-2,1],[-2,4,-2],[1,-2,1]] (zero on planes and on
# quadratics, sum of squares 36) is the outer product of this one with itself
_SECOND_DIFFERENCE = np.array([1.0, -2.0, 1.0], np.float32)
_NOISE_PIXELS = 2**17  # pixels sampled for the noise estimate
_BAND = 64  # rows per sampled band


class SubsetStats:
    """Reference-subset statistics per node: the rows of ``table`` are
    ``(m, var_f, hxx, hxy, hyy)``: pixels used, grey-level variance, and the
    2 x 2 Gauss-Newton matrix ``sum gx^2, sum gx gy, sum gy^2`` (NaN rows:
    not known yet; the affine IC-GN kernel fills them as it solves nodes)."""

    def __init__(self, table: np.ndarray):
        self.table = table

    @classmethod
    def empty(cls, n: int) -> SubsetStats:
        return cls(np.full((n, 5), np.nan))

    m = property(lambda self: self.table[:, 0])
    var_f = property(lambda self: self.table[:, 1])
    hxx = property(lambda self: self.table[:, 2])
    hxy = property(lambda self: self.table[:, 3])
    hyy = property(lambda self: self.table[:, 4])


def subset_statistics(f, fgx, fgy, nodes_x, nodes_y, slot, masks, half: int) -> SubsetStats:
    """Pixel count, grey-level variance and 2 x 2 Gauss-Newton matrix of
    every node's reference subset (mask component only)."""
    out = np.zeros((np.size(nodes_x), 5))
    slot = np.asarray(slot, np.int32)
    check_masks(slot, masks, half, out.shape[0])
    subset_stats(f, fgx, fgy, np.asarray(nodes_x, np.int64), np.asarray(nodes_y, np.int64),
                 slot, masks, int(half), out)
    return SubsetStats(out)


def image_noise(image: np.ndarray, roi: np.ndarray | None = None) -> float:
    """Standard deviation (grey levels) of white noise in ``image``.

    Immerkær's estimator: ``sqrt(pi/2) / 6`` times the mean absolute response
    to the mask ``[[1,-2,1],[-2,4,-2],[1,-2,1]]`` over the pixels whose 3 x 3
    neighbourhood lies in ``roi``. Texture finer than about two pixels adds
    to it (an over-estimate only makes the tests more lenient). Large images
    are sampled in bands of rows (about 130,000 pixels).
    """
    # an image read window by window (tiled runs) is sliced band by band
    img = image if hasattr(image, "shape") and hasattr(image, "__getitem__") else np.asarray(image)
    rows = img.shape[0]
    every = max(1, int(np.ceil(rows * img.shape[1] / _NOISE_PIXELS)))
    total = 0.0
    count = 0
    for r0 in range(0, rows - 2, _BAND * every):
        r1 = min(rows, r0 + _BAND + 2)
        band = np.asarray(img[r0:r1, :], np.float32)
        resp = ndimage.correlate1d(band, _SECOND_DIFFERENCE, axis=0, mode="nearest")
        resp = np.abs(ndimage.correlate1d(resp, _SECOND_DIFFERENCE, axis=1,
                                          mode="nearest")[1:-1, 1:-1])
        rband = None if roi is None else np.asarray(roi[r0:r1, :]) != 0
        if rband is not None and not rband.all():
            inside = ndimage.binary_erosion(rband, np.ones((3, 3), bool),
                                            border_value=0)[1:-1, 1:-1]
            resp = resp[inside]
        total += float(np.sum(resp, dtype=np.float64))
        count += resp.size
    return float(np.sqrt(np.pi / 2) / 6 * total / count) if count else 0.0


def displacement_variance(stats: SubsetStats, var_e: np.ndarray, gain: float) -> np.ndarray:
    """Noise variance (px²) of ``u`` and ``v`` per node, ``(n, 2)``.

    ``2 var_e S⁻¹ H S⁻¹`` (noise of variance ``var_e`` in both images): ``H``
    is the subset's 2 x 2 Gauss-Newton matrix; the gradients of the noisy
    reference carry noise energy ``m var_e gain`` per direction, so only the
    rest ``S`` (the speckle's, at least a tenth of ``H``) makes the subset
    match. NaN where ``var_e`` is unknown or ``S`` singular.
    """
    hxx, hxy, hyy = stats.hxx, stats.hxy, stats.hyy
    e = stats.m * var_e * gain
    sxx = np.maximum(hxx - e, 0.1 * hxx)
    syy = np.maximum(hyy - e, 0.1 * hyy)
    det = sxx * syy - hxy * hxy
    with np.errstate(invalid="ignore"):
        ok = (det > 0) & (stats.m > 0) & (var_e >= 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = syy / det
        b = -hxy / det
        c = sxx / det
        vu = 2.0 * var_e * (a * a * hxx + 2 * a * b * hxy + b * b * hyy)
        vv = 2.0 * var_e * (b * b * hxx + 2 * b * c * hxy + c * c * hyy)
    return np.where(ok[:, None], np.column_stack([vu, vv]), np.nan)


class Validity:
    """The validity tests of one image pair.

    Parameters
    ----------
    stats : SubsetStats
        Of the nodes' reference subsets.
    image_var : float
        Noise variance of the images (mean of both, grey levels²).
    gain : float
        Variance of the spline derivative of unit white noise
        (:func:`~napari_aldic.engine.dic.regularise.gradient_noise_gain`).
    params : DICParams
    """

    def __init__(self, stats: SubsetStats, image_var: float, gain: float,
                 params: DICParams):
        self.stats = stats
        self.image_var = float(image_var)
        self.gain = float(gain)
        self.params = params

    def residual(self, zncc: np.ndarray) -> np.ndarray:
        """Residual variance per pixel of each match, ``(1 - ZNCC) V`` (GL²)."""
        return (1.0 - zncc) * self.stats.var_f

    def level(self, zncc: np.ndarray, converged: np.ndarray) -> float:
        """Reference residual of a correct match: the median residual of the
        ``converged`` nodes, capped at ``NOISE_CAP`` times the image noise."""
        cap = NOISE_CAP * self.image_var
        ok = converged & np.isfinite(zncc) & np.isfinite(self.stats.var_f)
        if not ok.any():
            return cap
        return float(min(np.median(self.residual(zncc)[ok]), cap))

    def zncc_floor(self, zncc: np.ndarray, converged: np.ndarray) -> np.ndarray:
        """Lowest acceptable ZNCC per node: ``zncc_min``, raised by the
        relative test ``1 - ZNCC <= 0.1 + zncc_rel σ̂² / V``."""
        p = self.params
        floor = np.full(zncc.shape, float(p.zncc_min))
        if p.zncc_rel > 0:
            lvl = self.level(zncc, converged)
            with np.errstate(invalid="ignore", divide="ignore"):
                rel = 1.0 - MISMATCH_ALLOWANCE - p.zncc_rel * lvl / self.stats.var_f
            floor = np.maximum(floor, np.nan_to_num(rel, nan=-1.0, neginf=-1.0))
        return floor

    def noise_variance(self, zncc: np.ndarray) -> np.ndarray:
        """Predicted noise variance (px²) of ``u`` and ``v``, ``(n, 2)``, from
        each node's own residual; NaN where it has none (or ZNCC > 1)."""
        var_e = np.where(np.isfinite(zncc), self.residual(zncc), np.nan)
        return displacement_variance(self.stats, var_e, self.gain)

    def std(self, zncc: np.ndarray) -> np.ndarray:
        """Standard uncertainty (px) of ``u`` and ``v`` per node, ``(n, 2)``
        (a ZNCC rounded above 1 counts as a perfect match)."""
        return np.sqrt(self.noise_variance(np.minimum(zncc, 1.0)))

    def uncertain(self, zncc: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        """``candidates`` whose standard uncertainty of ``u`` or ``v`` exceeds
        ``max_uncertainty`` (or cannot be predicted)."""
        limit = self.params.max_uncertainty
        if limit is None:
            return np.zeros(zncc.shape, bool)
        s = self.std(zncc)
        return candidates & ~(np.max(s, axis=1) <= limit)

    def misfit(self, zncc_from: np.ndarray, zncc_to: np.ndarray) -> np.ndarray:
        """Displacement (px) that would lower a match's ZNCC from ``zncc_from``
        to ``zncc_to``, at most: the sum of squared differences grows by
        ``δᵀHδ = 2 m V ΔZNCC`` for a shift ``δ`` from the optimum, so
        ``|δ| <= sqrt(2 m V ΔZNCC / λ_min(H))`` (0 where ZNCC did not drop)."""
        st = self.stats
        tr = st.hxx + st.hyy
        lam = 0.5 * (tr - np.sqrt((st.hxx - st.hyy) ** 2 + 4 * st.hxy**2))
        drop = np.maximum(np.nan_to_num(zncc_from - zncc_to, nan=np.inf), 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.sqrt(2.0 * st.m * st.var_f * drop / lam)

    def global_mismatch(self, zncc_global, zncc_local, candidates) -> np.ndarray:
        """AL-DIC: ``candidates`` whose match with the global field's warp
        (``zncc_global``) is worse than their own affine match
        (``zncc_local``) by more than a misfit of ``GLOBAL_TOLERANCE`` plus
        ``GLOBAL_SIGMAS`` standard uncertainties of the local match."""
        s = np.max(self.std(zncc_local), axis=1)
        d = self.misfit(zncc_local, zncc_global)
        return candidates & ~(d <= GLOBAL_TOLERANCE + GLOBAL_SIGMAS * np.nan_to_num(s))

    def summary(self, zncc: np.ndarray, valid: np.ndarray) -> dict:
        """The noise levels behind the tests, for ``res.meta["validity"]``:
        image noise and match noise (grey levels), and the median standard
        uncertainty of the valid nodes (px)."""
        conv = valid & np.isfinite(zncc)
        s = np.max(self.std(zncc), axis=1)[valid]
        return {"image_noise_gl": float(np.sqrt(self.image_var)),
                "match_noise_gl": float(np.sqrt(max(self.level(zncc, conv), 0.0))),
                "median_std_px": float(np.median(s)) if s.size else None}

