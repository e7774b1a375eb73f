"""B-spline image interpolation with precomputed coefficients.

The image is prefiltered once (:mod:`~napari_aldic.engine.kernels.prefilter`,
the same coefficients as ``scipy.ndimage.spline_filter``) into B-spline
coefficients; sampling at a sub-pixel point is then a short weighted sum
(4 x 4 taps for cubic, 6 x 6 for quintic) done inside the Numba kernels of
:mod:`~napari_aldic.engine.kernels.bspline`.
Coefficients are padded by :data:`PAD` pixels (mirror extension) so the
kernels never bounds-check in their inner loop.

References: M. Unser, "Splines: a perfect fit for signal and image
processing", IEEE Signal Processing Magazine 16(6), 1999.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..kernels.bspline import PAD, sample_points, spline_gradients
from ..kernels.prefilter import GAINS, POLES, prefilter_2d, symmetric_fir_2d

__all__ = ["SplineImage", "prefilter", "sample", "reference_gradients", "PAD",
           "speckle_scale", "choose_order", "steepest_descent_gradients", "JACOBIAN_SIGMAS",
           "jacobian_smoothing", "PREFILTER_MARGIN"]

#: below this autocorrelation half-width (pixels) the speckle is so fine that
#: cubic B-splines leave a sub-pixel bias near 0.005-0.01 px; quintic ones
#: cut it 2-4x (measured on Gaussian-filtered noise, sigma 0.8-1.0 px)
FINE_SPECKLE_PX = 1.8

#: widths (px) of the Gaussians tried for the steepest-descent images
#: (:func:`jacobian_smoothing`): 0 (the plain spline gradient) to 3 px
JACOBIAN_SIGMAS = tuple(round(0.1 * i, 1) for i in range(31))

#: weight of the second-order noise term (the reference's gradient noise
#: meeting the residual's noise) in :func:`jacobian_smoothing`'s variance:
#: with 4 the chosen width sits at the measured optimum of synthetic speckle
#: of radius 1-4 px under 2-10 GL of noise (benchmarks/RESULTS.md)
_NOISE_PRODUCT = 4.0

#: pixels beyond the sampled area that make the B-spline coefficients of an
#: image window equal the whole image's to float precision (the recursive
#: prefilter's influence decays by a factor 0.43 or less per pixel): what
#: block-wise runs read around each block
PREFILTER_MARGIN = 48


@dataclass
class SplineImage:
    """B-spline coefficients of an image (padded by :data:`PAD`)."""

    coef: np.ndarray  # float32 (H + 2*PAD, W + 2*PAD)
    order: int  # 3 or 5
    shape: tuple[int, int]  # shape of the original image


def prefilter(image: np.ndarray, order: int = 3) -> SplineImage:
    """Compute padded B-spline coefficients of ``image``.

    Parameters
    ----------
    image : (H, W) array
        Grey values.
    order : {3, 5}
        Cubic or quintic B-spline.
    """
    if order not in (3, 5):
        raise ValueError(f"B-spline order must be 3 or 5, got {order}")
    img = np.asarray(image, dtype=np.float64)
    # scipy.ndimage.spline_filter(padded, order, mode="mirror") to 1e-12, in a
    # third of its time (float32 coefficients identical on speckle images)
    coef = np.pad(img, PAD, mode="reflect")
    prefilter_2d(coef, POLES[order], GAINS[order])
    return SplineImage(coef.astype(np.float32), order, img.shape)


def speckle_scale(image: np.ndarray, max_size: int = 512) -> float:
    """Half-width (pixels) at which the image's normalised autocorrelation
    falls to 0.5, from a central crop of at most ``max_size`` pixels: a
    measure of the speckle size (about 1.7 px for noise filtered with a
    Gaussian of sigma 1 px; 3-5 px for good DIC patterns)."""
    a = np.asarray(image, np.float64)
    h, w = a.shape
    c = min(h, w, max_size)
    y0, x0 = (h - c) // 2, (w - c) // 2
    a = a[y0:y0 + c, x0:x0 + c]
    a = a - a.mean()
    ac = np.fft.irfft2(np.abs(np.fft.rfft2(a)) ** 2, s=a.shape)
    if ac.flat[0] <= 0:
        return float("inf")
    ac = ac / ac.flat[0]
    n = min(c // 2, 32)
    prof = 0.5 * (ac[0, :n] + ac[:n, 0])  # along x and y (periodic autocorrelation)
    below = np.nonzero(prof < 0.5)[0]
    if below.size == 0:
        return float(n)
    i = int(below[0])
    return float(i - 1 + (prof[i - 1] - 0.5) / (prof[i - 1] - prof[i]))


def choose_order(interpolation: str, image: np.ndarray) -> int:
    """B-spline order for ``interpolation`` ("cubic", "quintic" or "auto":
    quintic when the speckle is finer than :data:`FINE_SPECKLE_PX`)."""
    if interpolation == "cubic":
        return 3
    if interpolation == "quintic":
        return 5
    return 5 if speckle_scale(image) < FINE_SPECKLE_PX else 3


def reference_gradients(spl: SplineImage) -> tuple[np.ndarray, np.ndarray]:
    """Exact derivatives of the spline at the integer pixel centres.

    Returns ``(gx, gy)``, float32 arrays of the image shape, where ``gx`` is
    d/dx (along columns) and ``gy`` d/dy (along rows).
    """
    if spl.order == 3:
        value = np.array([1.0, 4.0, 1.0]) / 6.0
        deriv = np.array([-0.5, 0.0, 0.5])
    else:
        value = np.array([1.0, 26.0, 66.0, 26.0, 1.0]) / 120.0
        deriv = np.array([-5.0, -50.0, 0.0, 50.0, 5.0]) / 120.0
    h, w = spl.shape
    gx = np.empty((h, w), np.float32)
    gy = np.empty((h, w), np.float32)
    spline_gradients(spl.coef, value, deriv, gx, gy)
    return gx, gy


def _radial_spectrum(f: np.ndarray, max_size: int, bins: int = 96):
    """Radially averaged periodogram of a central crop of at most
    ``max_size`` pixels (Hann-windowed, so the crop's edges do not leak into
    the high frequencies; white noise of variance ``σ²`` reads ``σ²``).

    Returns ``(power, k2, count, top)``: the mean power, the mean squared
    radial frequency (rad²/px²) and the number of Fourier bins of each ring
    (empty rings dropped), and the mean power of the outermost full ring
    (``0.85 π < |k| <= π``), where speckle has the least power.
    """
    a = np.asarray(f, np.float64)
    h, w = a.shape
    ch, cw = min(h, max_size), min(w, max_size)
    y0, x0 = (h - ch) // 2, (w - cw) // 2
    a = a[y0:y0 + ch, x0:x0 + cw]
    win = np.outer(np.hanning(ch), np.hanning(cw))
    a = (a - np.mean(a)) * win
    power = (np.abs(np.fft.rfft2(a)) ** 2 / np.sum(win**2)).ravel()
    k2 = ((2 * np.pi * np.fft.fftfreq(ch))[:, None] ** 2
          + (2 * np.pi * np.fft.rfftfreq(cw))[None, :] ** 2).ravel()
    k = np.sqrt(k2)
    top = (k > 0.85 * np.pi) & (k <= np.pi)
    ring = np.minimum((k / (np.pi * np.sqrt(2)) * bins).astype(np.int64), bins - 1)
    count = np.bincount(ring, minlength=bins)
    keep = count > 0
    mean = lambda v: np.bincount(ring, v, minlength=bins)[keep] / count[keep]  # noqa: E731
    return mean(power), mean(k2), count[keep], float(power[top].mean())


def jacobian_smoothing(f: np.ndarray, noise: float | None = None,
                       max_size: int = 512) -> float:
    """Standard deviation (px) of the Gaussian that smooths the reference for
    the IC-GN steepest-descent images (:func:`steepest_descent_gradients`).

    The instrumental-variable IC-GN step (:mod:`.icgn`) solves
    ``Σ J r = 0`` with ``J`` the gradient of the smoothed reference ``G f``.
    With white noise of power ``N`` per Fourier bin in both images its
    displacement variance is, per direction and to second order in the
    noise, ``V(G) ∝ Σ G² k² (2 N S + c N²) / (Σ G k² S)²``: ``S`` the
    speckle's power spectrum, the ``N²`` part the reference's gradient noise
    meeting the residual's noise (``c``: :data:`_NOISE_PRODUCT`). ``G = 1``
    is best without noise; the optimum in general is a Wiener filter. Here
    ``G`` is a Gaussian, its width the one of :data:`JACOBIAN_SIGMAS` that
    minimises ``V``, with ``S`` and ``N`` measured on a central crop
    (:func:`_radial_spectrum`): ``N = σ²``, ``σ`` the image noise
    (Immerkær's estimator, :func:`~.reliability.image_noise`, or the power
    of the outermost ring where that is lower: fine speckle inflates the
    former; ``noise`` overrides both), ``S`` the ring-averaged periodogram
    less ``N``. Noise-free or strong fine speckle gets little or no
    smoothing, coarse speckle under heavy noise the most.
    """
    from .reliability import image_noise

    img = np.asarray(f, np.float64)
    power, k2, count, top = _radial_spectrum(img, max_size)
    n = min(image_noise(img) ** 2, top) if noise is None else float(noise) ** 2
    if not n > 0:
        return 0.0
    signal = np.maximum(power - n, 0.0)
    best, best_v = 0.0, np.inf
    for s in JACOBIAN_SIGMAS:
        g = np.exp(-0.5 * s * s * k2)
        den = np.sum(count * g * k2 * signal)
        if not den > 0:
            continue
        v = np.sum(count * g * g * k2 * (2 * n * signal + _NOISE_PRODUCT * n * n)) / den**2
        if v < best_v * (1 - 1e-9):
            best, best_v = s, v
    return float(best)


def steepest_descent_gradients(f: np.ndarray, order: int,
                               sigma: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Reference gradients for the IC-GN steepest-descent images.

    The spline gradients (:func:`reference_gradients`) of ``f`` smoothed by
    a Gaussian of standard deviation ``sigma`` px (None:
    :func:`jacobian_smoothing`; 0: unsmoothed). Inverse-compositional
    Gauss-Newton converges where ``sum J r = 0`` with ``r`` the residual,
    which is zero at the true warp whatever ``J`` is: smoothing ``J`` leaves
    noise-free matches where they were and only stops the noise of the
    reference's highest frequencies from entering the estimate (the
    matched-filter argument: the best ``J`` is the noise-free gradient). The
    warp is still linearised with the exact gradients (:mod:`.icgn`), and
    the validity tests keep using them.
    """
    if sigma is None:
        sigma = jacobian_smoothing(f)
    if not sigma > 0:
        return reference_gradients(prefilter(f, order))
    return reference_gradients(prefilter(gaussian_smooth(f, sigma), order))


def gaussian_smooth(image: np.ndarray, sigma: float, truncate: float = 4.0) -> np.ndarray:
    """``ndimage.gaussian_filter(image, sigma, mode="reflect")`` in float64,
    bit for bit (the same weights, the same order of the sums:
    :func:`~..kernels.prefilter.symmetric_fir_2d`), in a tenth of its time
    for the few taps of the smoothing widths used here."""
    a = np.asarray(image, np.float64)
    r = int(truncate * float(sigma) + 0.5)
    if r < 1 or min(a.shape) <= r or a.ndim != 2:
        return ndimage.gaussian_filter(a, sigma, mode="reflect", truncate=truncate)
    x = np.arange(-r, r + 1)
    w = np.exp(-0.5 / (sigma * sigma) * x ** 2)
    out = np.empty(a.shape)
    symmetric_fir_2d(np.ascontiguousarray(a), w / w.sum(), out)
    return out


def sample(spl: SplineImage, x, y) -> np.ndarray:
    """Sample the spline image at points ``(x, y)`` (any matching shapes).

    Points must lie within the image (``0 <= x <= W-1``, ``0 <= y <= H-1``);
    a few pixels beyond that the mirror extension is used.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    x, y = np.broadcast_arrays(x, y)
    h, w = spl.shape
    lim = PAD - 3
    if x.size and (
        x.min() < -lim or y.min() < -lim or x.max() > w - 1 + lim or y.max() > h - 1 + lim
    ):
        raise ValueError("sample points lie outside the image (beyond the padded border)")
    out = np.empty(x.size, dtype=np.float64)
    sample_points(spl.coef, spl.order, np.ascontiguousarray(x).ravel(),
                  np.ascontiguousarray(y).ravel(), out)
    return out.reshape(x.shape)
