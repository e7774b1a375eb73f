"""Unit checks of the engine's building blocks."""

import json

import numpy as np
import pytest

from napari_aldic.engine import DICParams, Reason, correlate, load_result, synthetic as S
from napari_aldic.engine.dic.init_guess import ncc_search, ncc_search_widening
from napari_aldic.engine.dic.interpolation import prefilter, reference_gradients, sample
from napari_aldic.engine.dic.mesh import EDGE, make_grid
from napari_aldic.engine.dic.outliers import lattice_neighbours, median_test, median_test_at
from napari_aldic.engine.dic.subsets import split_subsets
from napari_aldic.engine.kernels.bspline import PAD


@pytest.mark.parametrize("order", [3, 5])
def test_spline_reproduces_cubic_polynomials(order):
    yy, xx = np.mgrid[0:60, 0:70].astype(float)

    def poly(x, y):
        return 3 + 0.5 * x - 0.2 * y + 0.01 * x * y + 0.003 * x**2 - 1e-4 * y**3

    spl = prefilter(poly(xx, yy), order)
    rng = np.random.default_rng(0)
    x = rng.uniform(12, 58, 500)
    y = rng.uniform(12, 48, 500)
    # exact away from the borders (mirror boundary only matters near them)
    np.testing.assert_allclose(sample(spl, x, y), poly(x, y), rtol=0, atol=2e-4)
    gx, gy = reference_gradients(spl)
    sl = (slice(12, 48), slice(12, 58))
    np.testing.assert_allclose(gx[sl], (0.5 + 0.01 * yy + 0.006 * xx)[sl], atol=2e-4)
    np.testing.assert_allclose(gy[sl], (-0.2 + 0.01 * xx - 3e-4 * yy**2)[sl], atol=2e-4)



@pytest.mark.parametrize("order", [3, 5])
def test_spline_gradients_are_the_stencil_bit_for_bit(order):
    """The row-wise (vectorised) gradient kernel sums each pixel's taps in the
    per-pixel order of the 2-D stencil, in float64: equal, bit for bit, to
    that stencil written out in NumPy, on a non-square image."""
    img = np.random.default_rng(order).uniform(0, 255, (37, 53))
    spl = prefilter(img, order)
    gx, gy = reference_gradients(spl)
    if order == 3:
        value, deriv = np.array([1.0, 4.0, 1.0]) / 6.0, np.array([-0.5, 0.0, 0.5])
    else:
        value = np.array([1.0, 26.0, 66.0, 26.0, 1.0]) / 120.0
        deriv = np.array([-5.0, -50.0, 0.0, 50.0, 5.0]) / 120.0
    r, (h, w) = value.size // 2, img.shape
    c = spl.coef.astype(np.float64)
    sx, sy = np.zeros((h, w)), np.zeros((h, w))
    for a in range(-r, r + 1):
        for b in range(-r, r + 1):
            blk = c[PAD + a:PAD + a + h, PAD + b:PAD + b + w]
            sx += value[a + r] * deriv[b + r] * blk
            sy += deriv[a + r] * value[b + r] * blk
    assert np.array_equal(gx, sx.astype(np.float32))
    assert np.array_equal(gy, sy.astype(np.float32))

def test_sample_outside_raises():
    spl = prefilter(np.ones((20, 20)) + np.eye(20), 3)
    with pytest.raises(ValueError, match="outside the image"):
        sample(spl, [50.0], [5.0])


def test_ncc_finds_integer_shift_exactly():
    ref, _ = S.speckle_pair((160, 160), None, seed=3)
    f = ref.astype(np.float32)
    g = np.zeros_like(f)
    g[7:, :-4] = f[:-7, 4:]  # material at X appears at X + (-4, +7)
    xs = np.array([60, 80, 100])
    ys = np.array([60, 80, 100])
    res = ncc_search(f, g, xs, ys, 15, 10)
    # the integer peak is exact; the parabola refinement stays close to it
    np.testing.assert_allclose(res.u, -4, atol=0.02)
    np.testing.assert_allclose(res.v, 7, atol=0.02)
    assert np.all(res.peak > 0.999)


def test_ncc_widening_reaches_large_shift():
    field = S.Translation(41.3, -22.6)
    ref, dfm = S.speckle_pair((256, 256), field, seed=6)
    f, g = ref.astype(np.float32), dfm.astype(np.float32)
    xs = np.array([70, 90])
    ys = np.array([150, 170])
    narrow = ncc_search(f, g, xs, ys, 15, 12)
    assert np.all(np.hypot(narrow.u - 41.3, narrow.v + 22.6) > 5)  # out of range
    wide = ncc_search_widening(f, g, xs, ys, 15, 12, 96)
    np.testing.assert_allclose(wide.u, 41.3, atol=0.3)
    np.testing.assert_allclose(wide.v, -22.6, atol=0.3)
    assert np.all(wide.search >= 48)


def test_grid_respects_roi_and_margin():
    roi = np.zeros((100, 120), bool)
    roi[20:80, 30:90] = True
    grid = make_grid(roi, 21, 5)
    assert np.all(roi[grid.y, grid.x])
    assert grid.x.min() >= 10 + EDGE and grid.y.min() >= 10 + EDGE
    assert np.all((grid.x - (10 + EDGE)) % 5 == 0)
    idx = grid.index_image()
    assert np.all(idx[grid.iy, grid.ix] == np.arange(grid.n))


def test_subset_component_excludes_other_crack_face():
    roi = np.ones((80, 80), bool)
    roi[40, :] = False  # a one-pixel crack
    grid = make_grid(roi, 15, 3)
    sub = split_subsets(roi, grid, 15)
    k = np.nonzero((grid.y == 38) & (grid.x == 38))[0][0]
    assert sub.slot[k] >= 0
    m = sub.masks[sub.slot[k]]
    # rows 31..45 of the subset: above the crack (rows 31..39) kept, rest dropped
    assert m[:9].all() and not m[9:].any()
    assert sub.fraction[k] == pytest.approx(9 / 15)
    assert sub.reason[k] == Reason.OK


def test_median_test_flags_planted_outlier_but_not_across_crack():
    roi = np.ones((120, 120), bool)
    roi[60, :] = False
    grid = make_grid(roi, 11, 6)
    u = np.where(grid.y < 60, 0.0, 3.0)  # a jump of 3 px across the crack
    v = np.zeros(grid.n)
    bad = np.nonzero((grid.x == 42) & (grid.y == 30))[0][0]
    u[bad] = 1.0
    nb = lattice_neighbours(grid, roi)
    out = median_test(u, v, np.ones(grid.n, bool), nb)
    assert out[bad] and out.sum() == 1


def test_repair_stage_reuses_the_median_test_only_for_the_same_inputs(monkeypatch):
    """``MedianTest`` (the repair stage's median test): the test reads only the
    trusted nodes' u, v, so the same trusted set and values give the last
    flags without testing again; a changed value at a trusted node, or a
    changed trusted set, tests again the nodes that read it (a few), and a
    large change tests every node. Values at untrusted nodes do not matter."""
    import napari_aldic.engine.dic.outliers as O

    roi = np.ones((120, 120), bool)
    grid = make_grid(roi, 11, 6)
    u, v = np.zeros(grid.n), np.zeros(grid.n)
    bad = np.nonzero((grid.x == 42) & (grid.y == 30))[0][0]
    u[bad] = 1.0
    nb = lattice_neighbours(grid, roi)
    full, part = [], []  # tests of every node; nodes of the partial tests

    def counted(u, *a):
        if u.size == grid.n:
            full.append(1)
        return median_test(u, *a)

    monkeypatch.setattr(O, "median_test", counted)
    monkeypatch.setattr(O, "median_test_at",
                        lambda nodes, *a: part.append(nodes.size) or median_test_at(nodes, *a))
    test = O.MedianTest()
    trusted = np.ones(grid.n, bool)
    trusted[0] = False
    first = test.flags(u, v, trusted, nb)
    assert first[bad] and first.sum() == 1
    u[0] = 50.0  # an untrusted node: the same inputs for the test
    first[:] = False  # the caller's copy, not the kept flags
    assert np.array_equal(test.flags(u, v, trusted.copy(), nb), median_test(u, v, trusted, nb))
    assert len(full) == 1 and not part
    u[bad] = 0.0  # a trusted node's value: its readers tested again
    assert not test.flags(u, v, trusted, nb).any() and len(full) == 1
    assert part == [25]  # the node and its 24 readers
    trusted[5] = False  # another trusted set: the readers of node 5
    test.flags(u, v, trusted, nb)
    assert len(full) == 1 and len(part) == 2
    u[:] = np.random.default_rng(0).normal(0, 0.1, grid.n)  # everything moved
    assert np.array_equal(test.flags(u, v, trusted, nb), median_test(u, v, trusted, nb))
    assert len(full) == 2


@pytest.mark.parametrize("quadtree", [False, True])
def test_incremental_median_test_equals_the_full_test(quadtree):
    """Small random changes of u, v and of the trusted set, on a ROI with a
    hole and a crack (neighbour tables that need not be symmetric) and on
    extra off-lattice nodes (the k-d tree neighbours): the flags that
    ``MedianTest`` keeps up to date equal a full test every time."""
    from napari_aldic.engine.dic.outliers import MedianTest

    roi = np.ones((160, 180), bool)
    yy, xx = np.mgrid[:160, :180]
    roi[(yy - 80) ** 2 + (xx - 90) ** 2 < 400] = False
    roi[40, 20:120] = False
    grid = make_grid(roi, 11, 6)
    if quadtree:
        from dataclasses import replace

        extra = np.column_stack([grid.x[::7] + 3, grid.y[::7] + 3])
        extra = extra[roi[extra[:, 1], extra[:, 0]]]
        grid = replace(grid, x=np.concatenate([grid.x, extra[:, 0]]),
                       y=np.concatenate([grid.y, extra[:, 1]]),
                       ix=np.concatenate([grid.ix, np.full(len(extra), -1)]),
                       iy=np.concatenate([grid.iy, np.full(len(extra), -1)]))
    rng = np.random.default_rng(1)
    u, v = rng.normal(0, 0.02, grid.n), rng.normal(0, 0.02, grid.n)
    trusted = rng.random(grid.n) > 0.05
    nb = lattice_neighbours(grid, roi)
    test = MedianTest()
    for _ in range(12):
        want = median_test(u, v, trusted, nb)
        assert np.array_equal(test.flags(u, v, trusted, nb), want)
        k = rng.choice(grid.n, 6, replace=False)
        u[k[:3]] += rng.choice([-2.0, 2.0], 3)  # new outliers, or healed ones
        trusted[k[3:]] = ~trusted[k[3:]]
    assert want.any()


def test_result_roundtrip_without_pickle(tmp_path):
    ref, dfm = S.speckle_pair((96, 96), S.Translation(0.25, 0.5), seed=2)
    res = correlate(ref, dfm, subset=21, step=6, search=8)
    path = res.save(tmp_path / "pair.npz")
    back = load_result(path)
    for name in ("x", "y", "u", "v", "dudx", "dvdy", "valid", "zncc", "reason"):
        np.testing.assert_array_equal(getattr(back, name), getattr(res, name))
    assert back.params == res.params
    assert back.meta["versions"]["napari-aldic"]
    with np.load(path, allow_pickle=False) as z:
        header = json.loads(str(z["header"]))
    assert header["params"]["subset"] == 21
    assert not list(tmp_path.glob("*.part"))
    np.testing.assert_array_equal(back.to_grid("u")[res.grid_iy, res.grid_ix],
                                  np.where(res.valid, res.u, np.nan))


def test_save_to_missing_folder_is_clear(tmp_path):
    ref, dfm = S.speckle_pair((64, 64), S.Translation(0.2, 0.1))
    res = correlate(ref, dfm, subset=15, step=8, search=6)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        res.save(tmp_path / "nope" / "r.npz")


def test_params_dict_roundtrip():
    p = DICParams(subset=41, step=5, search=30, seeds=((1, 2),), tol=1e-4)
    assert DICParams.from_dict(json.loads(json.dumps(p.to_dict()))) == p


def test_affine_field_inverse_is_exact():
    fld = S.Affine.strain_rotation(exx=0.02, eyy=-0.01, exy=0.005, angle_deg=3, center=(50, 40))
    X = np.array([0.0, 13.5, 99.0])
    Y = np.array([7.0, 55.0, 80.0])
    u, v = fld.displacement(X, Y)
    Xi, Yi = fld.inverse(X + u, Y + v)
    np.testing.assert_allclose(Xi, X, atol=1e-10)
    np.testing.assert_allclose(Yi, Y, atol=1e-10)


def test_generic_inverse_and_crack_gap():
    sin = S.Sinusoid(amplitude_u=1.5, amplitude_v=0.7, wavelength=50)
    X = np.linspace(0, 100, 11)
    Y = np.linspace(5, 60, 11)
    u, v = sin.displacement(X, Y)
    Xi, Yi = sin.inverse(X + u, Y + v)
    np.testing.assert_allclose(Xi, X, atol=1e-8)
    crack = S.ModeICrack(tip=(100, 50), amplitude=0.2)
    # a point in the opened gap behind the tip has no material
    gx, gy = crack.inverse(np.array([40.0]), np.array([50.0]))
    assert np.isnan(gx[0]) and crack.opening(40.0) > 2


def test_render_is_deterministic_and_pixel_integrated():
    pat = S.make_pattern((40, 40), seed=5)
    a = S.render(pat, (40, 40), bit_depth=None, n_quad=4)
    b = S.render(pat, (40, 40), bit_depth=None, n_quad=4)
    c = S.render(pat, (40, 40), bit_depth=None, n_quad=8)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(a, c, atol=0.05)  # quadrature converged
    shifted = S.render(pat, (40, 40), S.Translation(1.0, 0.0), bit_depth=None)
    np.testing.assert_allclose(shifted[:, 1:], a[:, :-1], atol=1e-9)
