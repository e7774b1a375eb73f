"""The 2-D B-spline prefilter (kernels/prefilter.py) against scipy.ndimage.

Cubic and quintic, lines shorter than the causal start's horizon (the exact
mirror start) and longer ones (the truncated sum), a one-sample axis (left
as it is); a wrong pole, gain or boundary start is off by 1e-2 or more of
the coefficients, the kernel agrees to 1e-12.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from napari_aldic.engine import synthetic
from napari_aldic.engine.dic.interpolation import PAD, prefilter
from napari_aldic.engine.kernels.prefilter import GAINS, POLES, prefilter_2d


@pytest.mark.parametrize("order", [3, 5])
@pytest.mark.parametrize("shape", [(1, 7), (2, 2), (5, 3), (40, 2), (9, 70), (64, 57)])
def test_prefilter_2d_matches_scipy_spline_filter(order, shape):
    img = np.random.default_rng(3).random(shape) * 200
    want = ndimage.spline_filter(img, order=order, mode="mirror", output=np.float64)
    got = img.copy()
    prefilter_2d(got, POLES[order], GAINS[order])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


@pytest.mark.parametrize("order", [3, 5])
def test_poles_are_the_knot_filters_roots(order):
    knots = {3: [1, 4, 1], 5: [1, 26, 66, 26, 1]}[order]
    for z in POLES[order]:
        assert abs(np.polyval(knots, z)) < 1e-12
    assert np.prod([(1 - z) * (1 - 1 / z) for z in POLES[order]]) == pytest.approx(
        GAINS[order], rel=1e-13)


@pytest.mark.parametrize("order", [3, 5])
def test_image_coefficients_equal_scipys_on_speckle(order):
    ref, _ = synthetic.speckle_pair((96, 128), synthetic.Translation(0.3, 0.1),
                                    noise=1.0, seed=4)
    spl = prefilter(ref, order)
    padded = np.pad(ref.astype(np.float64), PAD, mode="reflect")
    want = ndimage.spline_filter(padded, order=order, mode="mirror", output=np.float64)
    assert spl.coef.dtype == np.float32 and spl.coef.shape == padded.shape
    # float32 rounding of float64 values equal to 1e-12: identical but for ties
    assert np.mean(spl.coef != want.astype(np.float32)) < 1e-4
    np.testing.assert_allclose(spl.coef, want, rtol=1e-6, atol=1e-4)
