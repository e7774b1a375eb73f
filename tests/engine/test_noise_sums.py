"""The noise probes' window sums of AL-DIC's u_std propagation
(``kernels.noise_sums`` behind ``dic.uncertainty_aldic.noise_projector``)
against the general window-moments kernel on the same ±1 images."""

from __future__ import annotations

import numpy as np
import pytest

from napari_aldic.engine.dic.quality import SHAPE_TERMS
from napari_aldic.engine.dic.uncertainty_aldic import noise_projector, rademacher_bits
from napari_aldic.engine.dic.window_moments import window_moments
from napari_aldic.engine.kernels.moments import moment_terms


def _reference(jx, jy, images, x, y, half, mask, terms):
    """``Σ_subset J t n`` per node and image from ``window_moments`` (n, 2k, K)."""
    deg = max(p + q for p, q in terms)
    col = [moment_terms(deg).index(t) for t in terms]
    out = []
    for im in images:
        mom = window_moments([jx, jy, im], [(0, 2, deg), (1, 2, deg)], x, y, half, mask=mask,
                             centre=True)
        out.append(np.column_stack([mom[0][:, col], mom[1][:, col]]))
    return np.stack(out, axis=2)


@pytest.mark.parametrize("shape_function, holed", [("affine", False), ("quadratic", True)])
def test_probe_sums_match_the_window_moments(shape_function, holed):
    """Nodes on and off a lattice, windows clipped by every image edge, an ROI
    with a hole: the bit-packed probes and the same probes as images give the
    general kernel's sums to rounding (a wrong bit order, edge, moment order or
    centring is off by O(1))."""
    rng = np.random.default_rng(3)
    h, w = 97, 131
    jx = (30 * rng.standard_normal((h, w))).astype(np.float32)
    jy = (30 * rng.standard_normal((h, w))).astype(np.float32)
    gx, gy = np.meshgrid(np.arange(-4, w + 6, 9), np.arange(3, h + 2, 7))
    x = np.concatenate([gx.ravel(), rng.integers(0, w, 25)])
    y = np.concatenate([gy.ravel(), rng.integers(0, h, 25)])
    mask = None
    if holed:
        mask = np.ones((h, w), bool)
        mask[30:60, 40:75] = False
    terms = SHAPE_TERMS[shape_function]
    project = noise_projector(jx, jy, x, y, 21, mask, terms)
    got = project(np.random.default_rng(11), 5)
    bits = rademacher_bits(np.random.default_rng(11), (h, w), 5)
    images = [(2.0 * np.unpackbits(b)[:h * w].reshape(h, w) - 1).astype(np.float32)
              for b in bits]
    assert got.shape == (x.size, 2 * len(terms), 5)
    want = _reference(jx, jy, images, x, y, 10, mask, terms)
    scale = np.abs(want).max()
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-11 * scale)
    np.testing.assert_allclose(project.apply(images), want, rtol=0, atol=1e-11 * scale)
    # the probes are fresh ±1 images: about half the pixels +1, independent between probes
    ones = np.unpackbits(bits, axis=1)[:, :h * w].mean(axis=1)
    assert np.all(np.abs(ones - 0.5) < 0.02)
    assert abs(np.corrcoef(images[0].ravel(), images[1].ravel())[0, 1]) < 0.03


def test_probe_sums_of_nodes_outside_the_image_are_zero():
    rng = np.random.default_rng(4)
    jx, jy = (rng.standard_normal((40, 50)).astype(np.float32) for _ in range(2))
    project = noise_projector(jx, jy, np.array([-30, 20, 90]), np.array([10, 20, 10]), 11,
                              None, SHAPE_TERMS["affine"])
    got = project(np.random.default_rng(0), 3)
    assert np.all(got[[0, 2]] == 0) and np.all(got[1] != 0)


def test_projector_rejects_cubic_terms():
    z = np.zeros((20, 20), np.float32)
    with pytest.raises(ValueError, match="order"):
        noise_projector(z, z, np.array([10]), np.array([10]), 5, None, ((0, 0), (3, 0)))
