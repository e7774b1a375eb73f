"""The streaming window-moment kernel against brute-force per-node sums."""

import numpy as np
import pytest

from napari_aldic.engine.dic import window_moments as moments
from napari_aldic.engine.dic.window_moments import window_moments
from napari_aldic.engine.kernels.moments import HYPOT, ONES, centre_moments, moment_terms


def _brute(a, x, y, half, order, origin):
    """``{(p, q): Σ_window a X^p Y^q}`` and the matching ``Σ |a X^p Y^q|``
    (``origin=None``: about each node)."""
    h, w = a.shape
    out = {pq: np.zeros(x.size) for pq in moment_terms(order)}
    scale = {pq: np.zeros(x.size) for pq in moment_terms(order)}
    for n, (xi, yi) in enumerate(zip(x, y)):
        r0, r1 = np.clip([yi - half, yi + half + 1], 0, h)
        c0, c1 = np.clip([xi - half, xi + half + 1], 0, w)
        yy, xx = np.mgrid[r0:r1, c0:c1]
        cx, cy = (xi, yi) if origin is None else origin
        win = a[r0:r1, c0:c1]
        for p, q in out:
            t = win * (xx - cx) ** p * (yy - cy) ** q
            out[p, q][n] = t.sum()
            scale[p, q][n] = np.abs(t).sum()
    return out, scale


def _images(rng, h, w):
    f = rng.normal(100.0, 20.0, (h, w))
    gx = rng.normal(size=(h, w))
    gy = rng.normal(size=(h, w)).astype(np.float32)  # mixed dtypes are read as float64
    return f, gx, gy


def _check(res, images, products, mask, x, y, half, origin, tol=1e-11):
    m = np.ones(images[0].shape) if mask is None else mask.astype(float)
    for got, (i, j, order, *kind) in zip(res, products):
        u = np.ones(m.shape) if i == ONES else images[i].astype(np.float64)
        v = np.ones(m.shape) if j == ONES else images[j].astype(np.float64)
        a = (np.hypot(u, v) if kind == [HYPOT] else u * v) * m
        ref, scale = _brute(a, x, y, half, order, origin)
        assert got.shape == (x.size, len(ref))
        for t, pq in enumerate(moment_terms(order)):
            err = np.abs(got[:, t] - ref[pq])
            assert np.all(err <= tol * scale[pq] + 1e-300), (i, j, pq, err.max())


PRODUCTS = [(1, 1, 4), (1, 2, 2), (ONES, ONES, 4), (0, ONES, 0), (0, 0, 0),
            (1, 2, 0, HYPOT), (2, 0, 3)]


@pytest.mark.parametrize("masked", [False, True])
def test_full_lattice_matches_brute_force(masked):
    """Every node of a lattice reaching past the borders (clipped windows),
    an image taller than one accumulator epoch and wider than one block."""
    rng = np.random.default_rng(1)
    h, w = 150, 170
    images = _images(rng, h, w)
    mask = rng.random((h, w)) > 0.3 if masked else None
    xx, yy = np.meshgrid(np.arange(-4, w + 6, 6), np.arange(-3, h + 5, 7))
    x, y = xx.ravel(), yy.ravel()
    res = window_moments(images, PRODUCTS, x, y, 7, mask=mask)
    _check(res, images, PRODUCTS, mask, x, y, 7, ((w - 1) / 2, (h - 1) / 2))


def test_sparse_nodes_wide_windows_and_origin():
    """A random subset of a lattice, windows spanning several blocks and
    epochs, a given coordinate origin and a mask."""
    rng = np.random.default_rng(2)
    h, w = 200, 260
    images = _images(rng, h, w)
    mask = np.ones((h, w), bool)
    mask[60:90, 100:220] = False
    xx, yy = np.meshgrid(np.arange(3, w, 4), np.arange(5, h, 4))
    pick = rng.random(xx.size) < 0.05
    x, y = xx.ravel()[pick], yy.ravel()[pick]
    products = [(1, 2, 4), (ONES, ONES, 2), (2, 2, 0)]
    res = window_moments(images, products, x, y, 45, mask=mask, origin=(10.5, -3.0))
    _check(res, images, products, mask, x, y, 45, (10.5, -3.0))


def test_moments_about_each_node():
    """``centre=True``: the moments of ``X - x``, ``Y - y`` (the binomial
    shift of the raw ones loses a few digits to cancellation, hence the
    looser tolerance, relative to the sum of the absolute terms)."""
    rng = np.random.default_rng(4)
    h, w = 90, 110
    images = _images(rng, h, w)
    mask = rng.random((h, w)) > 0.2
    xx, yy = np.meshgrid(np.arange(2, w, 9), np.arange(1, h, 9))
    x, y = xx.ravel(), yy.ravel()
    products = [(1, 2, 4), (ONES, ONES, 4), (0, 0, 2)]
    res = window_moments(images, products, x, y, 8, mask=mask, centre=True)
    _check(res, images, products, mask, x, y, 8, None, tol=1e-8)


def test_row_bands_change_nothing(monkeypatch):
    """The nodes are split into bands of rows run in parallel; a band starts
    where the accumulator restarts anyway, so any number of bands gives the
    same bits (windows wholly above or below the image included), and the
    centring done inside the kernel is :func:`centre_moments` of the raw
    moments."""
    rng = np.random.default_rng(5)
    h, w = 400, 90  # several epochs
    images = _images(rng, h, w)
    mask = rng.random((h, w)) > 0.2
    xx, yy = np.meshgrid(np.arange(-4, w + 6, 5), np.arange(-20, h + 25, 6))
    x, y = xx.ravel(), yy.ravel()
    runs = []
    monkeypatch.setattr(moments, "PARALLEL_WORK", 0)  # split even this small job
    for bands in (1, 3, 50):
        monkeypatch.setattr(moments, "BANDS_PER_THREAD", bands)
        runs.append([window_moments(images, PRODUCTS, x, y, 9, mask=mask, centre=c)
                     for c in (False, True)])
    for raw, centred in runs[1:]:
        for a, b in zip(runs[0][0] + runs[0][1], raw + centred):
            np.testing.assert_array_equal(a, b)
    _check(runs[0][0], images, PRODUCTS, mask, x, y, 9, ((w - 1) / 2, (h - 1) / 2))
    dx, dy = x - (w - 1) / 2, y - (h - 1) / 2.0
    for raw, centred, (*_, order) in zip(runs[0][0], runs[0][1],
                                         [p[:3] for p in PRODUCTS]):
        want = centre_moments(np.ascontiguousarray(raw), dx.astype(float), dy, order)
        np.testing.assert_allclose(centred, want, rtol=1e-12,
                                   atol=1e-12 * np.abs(want).max())


def test_single_node_and_order_zero():
    rng = np.random.default_rng(3)
    f = rng.normal(size=(40, 30))
    (got,) = window_moments([f], [(0, ONES, 0)], [12, -20, 3], [20, 5, 60], 5)
    assert got.shape == (3, 1)
    assert got[0, 0] == pytest.approx(f[15:26, 7:18].sum(), rel=1e-12)
    # windows wholly outside the image sum nothing
    assert np.all(got[1:, 0] == 0.0)


def test_bad_input_is_refused():
    f = np.zeros((10, 10))
    with pytest.raises(ValueError, match="missing image"):
        window_moments([f], [(0, 1, 2)], [5], [5], 2)
    with pytest.raises(ValueError, match="orders"):
        window_moments([f], [(0, 0, 5)], [5], [5], 2)
    with pytest.raises(ValueError, match="mask shape"):
        window_moments([f], [(0, 0, 2)], [5], [5], 2, mask=np.ones((9, 10), bool))
    with pytest.raises(ValueError, match="differ in shape"):
        window_moments([f, np.zeros((10, 11))], [(0, 1, 2)], [5], [5], 2)
