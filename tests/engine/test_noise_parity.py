"""Local IC-GN under heavy grey-level noise, against the analytic noise bound.

For a translation and white noise of variance ``s2`` in both images, no
unbiased subset estimator does better than ``var(u) + var(v) = 2 s2 tr(H^-1)``
with ``H`` the 2 x 2 Gauss-Newton matrix of the *noise-free* reference subset
(the Cramér-Rao bound of the two-image problem). Steepest-descent images built
from the raw spline derivative of the noisy reference carry its noise at the
highest frequencies and came out ~19 % above that bound at 10 grey levels; the
smoothed ones (:func:`~napari_aldic.engine.dic.interpolation.steepest_descent_gradients`)
come within ~10 %.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from napari_aldic.engine import synthetic as S
from napari_aldic.engine.dic.icgn import icgn_solve
from napari_aldic.engine.dic.images import prepare_images
from napari_aldic.engine.dic.interpolation import prefilter, reference_gradients

U, V = 0.3, -0.45
HALF = 10
NOISE = 10.0
SIZE = 160


def _pair(seed):
    """Noise-free float renders of a translated pattern, and noisy copies."""
    pat = S.make_pattern((SIZE, SIZE), seed=seed)
    f0 = S.render(pat, (SIZE, SIZE), None, bit_depth=None, n_quad=2)
    g0 = S.render(pat, (SIZE, SIZE), S.Translation(U, V), bit_depth=None, n_quad=2)
    rng = np.random.default_rng(seed + 100)
    return f0, f0 + rng.normal(0, NOISE, f0.shape), g0 + rng.normal(0, NOISE, f0.shape)


def _bound(clean, nx, ny):
    """Mean over nodes of ``2 s2 tr(H^-1)`` (px²) from the noise-free reference."""
    gx, gy = reference_gradients(prefilter(clean, 3))
    w = 2 * HALF + 1

    def box(a):
        return ndimage.uniform_filter(a.astype(float), w, mode="constant")[ny, nx] * w * w

    hxx, hxy, hyy = box(gx * gx), box(gx * gy), box(gy * gy)
    return float(np.mean(2 * NOISE**2 * (hxx + hyy) / (hxx * hyy - hxy**2)))


def test_local_icgn_noise_near_the_analytic_bound_at_10_grey_levels():
    sq = {"smoothed": 0.0, "raw": 0.0}
    bound = 0.0
    for seed in range(1, 5):
        clean, f, g = _pair(seed)
        im = prepare_images(f, g, "cubic")
        xs, ys = np.meshgrid(np.arange(HALF + 2, SIZE - HALF - 2, 3),
                             np.arange(HALF + 2, SIZE - HALF - 2, 3))
        nx, ny = xs.ravel().astype(np.int64), ys.ravel().astype(np.int64)
        args = (nx, ny, np.zeros((nx.size, 6)), np.ones(nx.size, bool),
                -np.ones(nx.size, np.int32), np.ones((0, 21, 21), np.uint8), HALF)
        for name, (gx, gy) in {"smoothed": (im.jgx, im.jgy), "raw": (im.fgx, im.fgy)}.items():
            p, _, _, reason = icgn_solve(im.f, gx, gy, im.g_spline, *args)
            assert np.all(reason == 0)
            sq[name] += float(np.mean((p[:, 0] - U) ** 2 + (p[:, 3] - V) ** 2))
        bound += _bound(clean, nx, ny)
    ratio = {k: np.sqrt(v / bound) for k, v in sq.items()}
    # what Local DIC uses: within 15 % of the bound (measured 1.10 over 6 seeds)
    assert ratio["smoothed"] < 1.15, ratio
    # and clearly below the raw spline gradients on the same images (measured -8 %)
    assert ratio["smoothed"] < 0.96 * ratio["raw"], ratio
    # a noise-free match stays where it was (any J solves sum J r = 0 at the truth)
    assert ratio["smoothed"] > 0.9  # no estimator beats the bound by more than chance
