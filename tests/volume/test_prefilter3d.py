"""The parallel tricubic prefilter and knot gradients against scipy.ndimage.

Lines shorter than the filter's horizon (the exact mirror start) and longer
ones (the truncated sum) both; a wrong pole, gain or boundary start is off
by 1e-2 or more of the coefficients.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from napari_aldic.engine.kernels.bspline3d import PAD3
from napari_aldic.engine.volume.spline import coefficients, gradients


@pytest.mark.parametrize("shape", [(3, 7, 5), (40, 2, 33), (9, 31, 50)])
def test_coefficients_match_scipy_spline_filter(shape):
    vol = np.random.default_rng(1).random(shape).astype(np.float32) * 200
    ref = ndimage.spline_filter(vol.astype(np.float64), order=3, mode="mirror")
    want = np.pad(ref.astype(np.float32), PAD3, mode="reflect")
    got = coefficients(vol)
    assert got.dtype == np.float32 and got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-4)


def test_knot_gradients_are_the_spline_derivative():
    vol = np.random.default_rng(2).random((12, 14, 16)).astype(np.float32) * 100
    c = coefficients(vol)
    g = gradients(c)
    # the spline's derivative at the knots, by scipy's order-3 interpolation of ref
    coef = ndimage.spline_filter(vol.astype(np.float64), order=3, mode="mirror")
    z, y, x = np.mgrid[2:10, 2:12, 2:14].astype(float)
    eps = 1e-4
    for a, (dz, dy, dx) in enumerate(((0, 0, eps), (0, eps, 0), (eps, 0, 0))):
        hi = ndimage.map_coordinates(coef, [z + dz, y + dy, x + dx], order=3, prefilter=False)
        lo = ndimage.map_coordinates(coef, [z - dz, y - dy, x - dx], order=3, prefilter=False)
        np.testing.assert_allclose(g[a, 2:10, 2:12, 2:14], (hi - lo) / (2 * eps), atol=2e-3)
