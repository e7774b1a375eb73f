"""The fast paths of the static-feature tests and of the prefilter give what
the plain definitions give (issue 22, speed): the flat-pixel map (windows
from summed-area tables, the 75th percentile counted instead of sorted when
the noise bound decides), the Gaussian smoothing of the steepest-descent
images (bit for bit), the flat pixels per node window (from the few flat
pixels' positions), and the zero-motion evidence, whose ``z`` is skipped
where ``S / D`` cannot flag a node (the flags stay the same)."""

import numpy as np
import pytest
from scipy import ndimage as ndi

from napari_aldic.engine import synthetic
from napari_aldic.engine.dic import static as S
from napari_aldic.engine.dic.icgn import icgn_solve
from napari_aldic.engine.dic.images import prepare_images
from napari_aldic.engine.dic.interpolation import JACOBIAN_SIGMAS, gaussian_smooth
from napari_aldic.engine.dic.mesh import make_grid
from napari_aldic.engine.dic.subsets import integral_image, rect_sums, split_subsets

FIELD = synthetic.Affine.strain_rotation(exx=0.005, center=(128, 128), t=(1.3, -0.6))


def _flat_by_definition(f, g, roi, image_var):
    """The flat-pixel map as first written: two uniform filters per image and
    np.percentile, no short cuts."""
    thr2 = (S.FLAT_NOISE * np.sqrt(image_var) + S.FLAT_GL) ** 2
    flat = roi.copy()
    for a in (f, g):
        a = np.asarray(a, np.float64)
        m = ndi.uniform_filter(a, S.FLAT_WINDOW)
        var = ndi.uniform_filter(a * a, S.FLAT_WINDOW) - m * m
        typical = np.percentile(var[roi], 75)
        flat &= (var <= thr2) & (var <= S.FLAT_CONTRAST ** 2 * typical)
    return flat


def _pair(scale, noise, bar, shape=(256, 256)):
    r, d = synthetic.speckle_pair(shape, FIELD, noise=noise)
    rng = np.random.default_rng(5)
    r = (r * scale + rng.normal(0, noise, r.shape)).astype(np.float32)
    d = (d * scale + rng.normal(0, noise, d.shape)).astype(np.float32)
    if bar:
        r[:, 100:124] = 40
        d[:, 100:124] = 40
    return r, d


@pytest.mark.parametrize("scale,noise,bar,roi_cut,decided", [
    (1.0, 0.5, True, False, True),     # speckle beside a bar: the noise bound decides
    (1.0, 0.5, False, True, True),     # clean speckle, a ROI with a hole
    (0.05, 3.0, True, False, False),   # faint speckle under heavy noise: the percentile decides
    (0.05, 3.0, True, True, False),
])
def test_flat_pixels_match_their_definition(scale, noise, bar, roi_cut, decided):
    f, g = _pair(scale, noise, bar, shape=(250, 233))
    roi = np.ones(f.shape, bool)
    if roi_cut:
        roi[60:120, 150:200] = False
    var = noise ** 2
    expect = _flat_by_definition(f, g, roi, var)
    got = S._flat_pixels(f, g, roi, var)
    assert np.array_equal(got, expect)
    if bar:
        assert got.sum() > 1000  # the bar's inside is flat
    thr2 = (S.FLAT_NOISE * noise + S.FLAT_GL) ** 2
    decides = S._typical_at_least(S._window_var(f), roi, bool(roi.all()),
                                  thr2 / S.FLAT_CONTRAST ** 2)
    assert decides == decided  # both branches are exercised


def test_window_variance_mirrors_the_border_like_uniform_filter():
    rng = np.random.default_rng(2)
    a = rng.integers(0, 255, (131, 257)).astype(np.float32)
    m = ndi.uniform_filter(a.astype(np.float64), S.FLAT_WINDOW)
    ref = ndi.uniform_filter(a.astype(np.float64) ** 2, S.FLAT_WINDOW) - m * m
    assert np.allclose(S._window_var(a), ref, rtol=0, atol=1e-8)


@pytest.mark.parametrize("share", [0.0, 1e-4, 0.01, 0.3])
def test_window_counts_sparse_equal_the_summed_area_table(share):
    rng = np.random.default_rng(5)
    flat = rng.random((300, 260)) < share
    flat[40:60, 100:180] = share > 0.005  # a flat bar among scattered pixels
    grid = make_grid(np.ones(flat.shape, bool), 21, 7)
    x, y, h = grid.x.astype(np.int64), grid.y.astype(np.int64), 10
    want = rect_sums(integral_image(flat), x - h, y - h, x + h, y + h)
    got = S._window_counts(flat, x, y, h)
    assert np.array_equal(got, want)
    sparse = np.count_nonzero(flat) <= S.SPARSE_FLAT * x.size
    assert sparse == (share < 0.01)  # both paths are exercised


def test_gaussian_smooth_is_ndimage_bit_for_bit():
    rng = np.random.default_rng(1)
    img = rng.normal(100, 30, (97, 140)).astype(np.float32)
    for sigma in JACOBIAN_SIGMAS[1:]:
        for a in (img, img[:5, :9]):
            expect = ndi.gaussian_filter(np.asarray(a, np.float64), sigma, mode="reflect")
            assert np.array_equal(gaussian_smooth(a, sigma), expect), sigma


def test_zero_motion_z_skipped_only_where_it_cannot_flag():
    r, d = synthetic.speckle_pair((256, 256), FIELD, noise=0.5)
    r, d = r.astype(np.float32), d.astype(np.float32)
    r[:, :128] = 0  # the static occluder of issue 22
    d[:, :128] = 0
    roi = np.ones(r.shape, bool)
    im = prepare_images(r, d, "cubic")
    grid = make_grid(roi, 31, 8)
    sub = split_subsets(roi, grid, 31)
    ut, vt = FIELD.displacement(grid.x, grid.y)
    p0 = np.zeros((grid.n, 6))
    p0[:, 0], p0[:, 3] = ut, vt
    active = sub.reason == 0
    jgx, jgy = (im.fgx, im.fgy) if im.jgx is None else (im.jgx, im.jgy)
    ev = []
    for extra in ((), (S.STATIC_FRACTION,)):
        out = np.full((grid.n, 2), np.nan)
        icgn_solve(im.f, jgx, jgy, im.g_spline, grid.x, grid.y, p0, active, sub.slot,
                   sub.masks, 15, lin=(im.fgx, im.fgy),
                   static=(im.g, 0.25, S.STATIC_MIN_MOTION, out) + extra)
        ev.append(out)
    full, fast = ev
    tested = np.isfinite(full[:, 0])
    assert tested.sum() > 100
    assert np.array_equal(np.isfinite(fast[:, 0]), tested)
    assert np.allclose(fast[tested, 0], full[tested, 0], rtol=1e-12, atol=1e-15)
    above = tested & (full[:, 0] > S.STATIC_FRACTION)
    assert above.sum() > 10 and (~above & tested).sum() > 10  # both kinds of node
    assert np.allclose(fast[above, 1], full[above, 1], rtol=1e-9)
    assert np.all(np.isnan(fast[tested & ~above, 1]))

    def flags(e):
        with np.errstate(invalid="ignore"):
            return (e[:, 1] > S.STATIC_Z) & (e[:, 0] > S.STATIC_FRACTION)
    assert np.array_equal(flags(fast), flags(full))
    assert flags(full).sum() > 0  # the occluder is caught


@pytest.mark.parametrize("dtype", [bool, np.uint8])
def test_integral_image_sums_every_rectangle_exactly(dtype):
    """The summed-area table (NumPy's cumulative sums since issue 25) gives
    the exact count of every rectangle, int64, on boolean and uint8 masks."""
    from napari_aldic.engine.dic.subsets import integral_image, rect_sums

    rng = np.random.default_rng(3)
    mask = (rng.random((37, 23)) > 0.4).astype(dtype)
    ii = integral_image(mask)
    assert ii.dtype == np.int64 and ii.shape == (38, 24)
    assert (ii[0] == 0).all() and (ii[:, 0] == 0).all()
    x0, y0 = rng.integers(0, 20, 50), rng.integers(0, 30, 50)
    x1, y1 = x0 + rng.integers(0, 3, 50), y0 + rng.integers(0, 6, 50)
    want = [mask[a:b + 1, c:d + 1].sum() for a, b, c, d in zip(y0, y1, x0, x1)]
    assert np.array_equal(rect_sums(ii, x0, y0, x1, y1), want)


def test_integral_image_rejects_float_images():
    from napari_aldic.engine.dic.subsets import integral_image

    with pytest.raises(ValueError, match="boolean or unsigned"):
        integral_image(np.ones((4, 4)))


def _lag_block_reference(f, x0, y0, h, mask, cx, cy, w):
    """NumPy NCC of a node's (masked) reference subset with the reference
    shifted by every lag of the block around ``(cx, cy)``; NaN off the image."""
    a, b = np.nonzero(mask)
    fs = f[y0 - h + a, x0 - h + b].astype(np.float64)
    fz = fs - fs.mean()
    block = np.full((2 * w + 1, 2 * w + 1), np.nan)
    for i in range(2 * w + 1):
        for j in range(2 * w + 1):
            yy, xx = y0 - h + a + cy + i - w, x0 - h + b + cx + j - w
            if yy.min() < 0 or xx.min() < 0 or yy.max() >= f.shape[0] or xx.max() >= f.shape[1]:
                continue
            g = f[yy, xx].astype(np.float64)
            block[i, j] = (fz @ g) / (np.sqrt(fz @ fz) * np.sqrt(g @ g - g.sum() ** 2 / g.size))
    return block


def test_lag_peaks_matches_a_numpy_ncc_for_full_and_masked_subsets():
    """The periodic-texture kernel (rows read contiguously, the mask's bounding
    box tested once per lag) against a NumPy NCC: the peak lag and its
    parabola-refined height, for a full subset and for a masked one near the
    border whose full square would leave the image at these lags while its
    mask does not (a test on the square instead of the mask fails here)."""
    from napari_aldic.engine.kernels.static import lag_peaks

    yy, xx = np.mgrid[:64, :64]
    rng = np.random.default_rng(5)
    # periodic along x (7 px); a product, so that every x lag but the period
    # decorrelates the whole subset, however narrow its mask
    f = (np.cos(2 * np.pi * xx / 7) * np.cos(2 * np.pi * yy / 13)
         + 0.05 * rng.standard_normal((64, 64))).astype(np.float32)
    h, w, lag = 5, 2, (7, 0)
    nx, ny = np.array([30, 54], np.int64), np.array([30, 20], np.int64)
    masks = np.zeros((1, 2 * h + 1, 2 * h + 1), np.uint8)
    masks[0, :, :4] = 1  # node 1: the left four columns only
    slot = np.array([-1, 0], np.int32)
    cand = np.array([[lag], [lag]], np.int64)
    out = np.empty((2, 3))
    lag_peaks(0, 2, f, nx, ny, slot, masks, h, cand, np.ones(2, np.int64), w, out)
    full = np.ones((2 * h + 1, 2 * h + 1), bool)
    for k, mask in enumerate((full, masks[0].astype(bool))):
        assert nx[k] - h + lag[0] + w + 2 * h > 63 or k == 0  # node 1's square leaves
        block = _lag_block_reference(f, nx[k], ny[k], h, mask, *lag, w)
        bi, bj = np.unravel_index(np.nanargmax(block), block.shape)
        assert (bi, bj) == (w, w)  # the period, inside the block
        best = block[bi, bj]
        val = best
        for a0, a2 in ((block[bi, bj - 1], block[bi, bj + 1]),
                       (block[bi - 1, bj], block[bi + 1, bj])):
            den = a0 - 2 * best + a2
            if den < 0:
                val += -0.125 * (a2 - a0) ** 2 / den
        assert out[k, 1:].tolist() == [7.0, 0.0]
        assert abs(out[k, 0] - min(val, 1.0)) < 1e-9
        assert 0.9 < out[k, 0] <= 1.0
