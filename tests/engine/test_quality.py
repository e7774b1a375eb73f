"""Measurement quality: SSSIG/MIG, interpolated noise, subset advice, noise floor."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from napari_aldic.engine import (
    SubsetAdvice,
    advise_subset,
    correlate,
    export_result,
    load_result,
    noise_floor,
    synthetic as S,
)
from napari_aldic.engine.dic.interpolation import prefilter, reference_gradients
from napari_aldic.engine.dic.quality import (
    SHAPE_TERMS,
    interpolated_noise_factor,
    speckle_quality,
    static_uncertainty,
)


def test_sssig_and_mig_of_a_ramp_are_exact():
    yy, xx = np.mgrid[0:96, 0:96].astype(float)
    img = 3.0 * xx + 2.0 * yy  # spline gradients of a plane are exact away from the edges
    x = np.array([40, 48, 56])
    y = np.array([40, 44, 50])
    q = speckle_quality(img, x, y, 21)
    np.testing.assert_allclose(q.sssig_x, 9.0 * 441, rtol=1e-5)
    np.testing.assert_allclose(q.sssig_y, 4.0 * 441, rtol=1e-5)
    np.testing.assert_allclose(q.sssig, 4.0 * 441, rtol=1e-5)
    np.testing.assert_allclose(q.mig, np.sqrt(13.0), rtol=1e-5)
    np.testing.assert_allclose(q.m, 441)
    # grey-level variance of a plane over a 21 x 21 window: (9 + 4) * (21² - 1) / 12
    np.testing.assert_allclose(q.var_f, 13 * 440 / 12, rtol=1e-6)


@pytest.mark.parametrize("shape_function", ["affine", "quadratic"])
def test_gauss_newton_matrix_equals_a_brute_force_sum(shape_function):
    img, _ = S.speckle_pair((120, 130), S.Translation(0, 0), noise=2.0, seed=4)
    roi = np.ones(img.shape, bool)
    roi[:, 70:74] = False  # a crack through some subsets
    x, y, sub = np.array([30, 66, 95]), np.array([40, 60, 75]), 25
    q = speckle_quality(img, x, y, sub, roi, shape_function=shape_function)
    gx, gy = (a.astype(float) for a in reference_gradients(prefilter(img.astype(float), 3)))
    h = sub // 2
    terms = SHAPE_TERMS[shape_function]
    for k in range(3):
        dy, dx = np.mgrid[-h:h + 1, -h:h + 1].astype(float)
        win = (slice(y[k] - h, y[k] + h + 1), slice(x[k] - h, x[k] + h + 1))
        m = roi[win]
        mono = [dx**p * dy**q_ for p, q_ in terms]
        jac = np.array([gx[win] * t for t in mono] + [gy[win] * t for t in mono])[:, m]
        np.testing.assert_allclose(q.hessian[k], jac @ jac.T, rtol=1e-6,
                                   atol=1e-6 * np.abs(jac @ jac.T).max())
        np.testing.assert_allclose(q.sssig_x[k], np.sum(gx[win][m] ** 2), rtol=1e-6)


def test_smoothed_jacobian_matrices_equal_brute_force_sums():
    """``cross`` = Σ J ∇fᵀ of the smoothed steepest-descent images against
    the plain gradients, and the noise parts = gain x Σ t tᵀ on the diagonal
    blocks (quadratic, with a ROI)."""
    from napari_aldic.engine.dic.interpolation import steepest_descent_gradients
    from napari_aldic.engine.dic.quality import filter_gains

    img, _ = S.speckle_pair((120, 130), S.Translation(0, 0), noise=2.0, seed=4)
    img = img.astype(float)
    roi = np.ones(img.shape, bool)
    roi[:, 70:74] = False
    x, y, sub, sigma = np.array([30, 66, 95]), np.array([40, 60, 75]), 25, 0.8
    jx, jy = steepest_descent_gradients(img, 3, sigma)
    q = speckle_quality(img, x, y, sub, roi, shape_function="quadratic",
                        jacobian=(jx, jy, sigma))
    gx, gy = (a.astype(float) for a in reference_gradients(prefilter(img, 3)))
    _, gain_j, gain_c = filter_gains(sigma, 3)
    h = sub // 2
    dy, dx = np.mgrid[-h:h + 1, -h:h + 1].astype(float)
    for k in range(3):
        win = (slice(y[k] - h, y[k] + h + 1), slice(x[k] - h, x[k] + h + 1))
        m = roi[win]
        mono = np.array([dx**p * dy**q_ for p, q_ in SHAPE_TERMS["quadratic"]])
        jj = np.concatenate([jx[win] * mono, jy[win] * mono])[:, m]
        jg = np.concatenate([gx[win] * mono, gy[win] * mono])[:, m]
        tt = mono[:, m] @ mono[:, m].T
        zero = np.zeros_like(tt)
        ones = np.block([[tt, zero], [zero, tt]])
        for got, want in ((q.cross[k], jj @ jg.T), (q.hessian[k], jj @ jj.T),
                          (q.noise[k], gain_j * ones), (q.cross_noise[k], gain_c * ones)):
            np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6 * np.abs(want).max())


def test_interpolated_noise_factor_is_the_variance_of_interpolated_noise():
    rng = np.random.default_rng(0)
    noise = rng.normal(size=(400, 400))
    for t in (0.0, 0.25, 0.5):
        moved = ndimage.shift(noise, (0, t), order=3, mode="grid-wrap")
        assert interpolated_noise_factor(t, 0.0) == pytest.approx(moved.var(), rel=0.02)
    assert interpolated_noise_factor(3.0, -2.0) == pytest.approx(1.0, abs=1e-9)
    assert interpolated_noise_factor(0.5, 0.5) < 0.6  # a wrong (unreduced) model gives 1


def test_pan_rule_is_the_translation_limit_of_the_model():
    """Without noise in the gradients and with translation-only subsets the
    prediction reduces to Pan's sqrt(2) sigma / sqrt(SSSIG)."""
    img, _ = S.speckle_pair((128, 128), S.Translation(0, 0), seed=2, bit_depth=None)
    x = y = np.array([50, 64, 80])
    q = speckle_quality(img, x, y, 31)
    k = q.hessian.shape[1] // 2
    q.hessian = q.hessian[:, [0, k]][:, :, [0, k]]  # keep the translation block
    q.noise = np.zeros_like(q.hessian)
    std = static_uncertainty(q, 4.0)
    hxx, hxy, hyy = q.hessian[:, 0, 0], q.hessian[:, 0, 1], q.hessian[:, 1, 1]
    det = hxx * hyy - hxy**2
    np.testing.assert_allclose(std[:, 0], np.sqrt(2) * 4.0 * np.sqrt(hyy / det), rtol=1e-9)
    # with uncorrelated gradient directions this is exactly sqrt(2) sigma / sqrt(SSSIG_x)
    assert np.all(np.abs(hxy) < 0.3 * np.sqrt(hxx * hyy))
    np.testing.assert_allclose(std[:, 0], np.sqrt(2) * 4.0 / np.sqrt(q.sssig_x), rtol=0.1)


def test_result_carries_quality_fields_through_save_and_exports(tmp_path):
    ref, dfm = S.speckle_pair((128, 128), S.Translation(1.3, 0.4), noise=3.0, seed=1)
    for method in ("local", "aldic"):
        res = correlate(ref, dfm, subset=21, step=12, method=method)
        ok = res.valid
        for name in ("u_std", "v_std", "sssig", "mig"):
            vals = getattr(res, name)
            assert vals is not None and vals.shape == res.x.shape
            assert np.isfinite(vals[ok]).all() and (vals[ok] > 0).all()
        back = load_result(res.save(tmp_path / f"{method}.npz"))
        np.testing.assert_array_equal(back.sssig, res.sssig)
        np.testing.assert_array_equal(back.mig, res.mig)
    out = export_result(res, tmp_path / "r.csv")
    header = next(ln for ln in out.read_text(encoding="utf-8").splitlines()
                  if not ln.startswith("#"))
    for name in ("u_std [px]", "v_std [px]", "sssig", "mig"):
        assert name in header


def test_advice_picks_the_smallest_subset_meeting_the_target_and_is_right():
    ref, _ = S.speckle_pair((256, 256), S.Translation(0, 0), noise=4.0, seed=5)
    adv = advise_subset(ref, target_noise=0.015, subsets=(11, 15, 21, 31, 41))
    assert isinstance(adv, SubsetAdvice)
    assert adv.noise == pytest.approx(4.0, rel=0.1)
    med = [r["median_std_px"] for r in adv.rows]
    assert all(a > b for a, b in zip(med, med[1:]))  # larger subsets: less noise
    meets = [r["subset"] for r in adv.rows if r["fraction"] >= adv.coverage]
    assert adv.recommended == meets[0] and adv.recommended in (15, 21, 31)
    # the advised subset's measured noise on a static pair (new noise, same pattern)
    ref0, dfm0 = S.speckle_pair((256, 256), S.Translation(0, 0), noise=4.0, seed=5)
    res = correlate(ref0, dfm0, subset=adv.recommended, step=10)
    d = np.concatenate([res.u[res.valid], res.v[res.valid]])
    assert np.std(d) <= 1.2 * adv.target
    row = next(r for r in adv.rows if r["subset"] == adv.recommended)
    assert np.std(d) == pytest.approx(row["median_std_px"], rel=0.25)


def test_advice_rejects_bad_input():
    img = np.random.default_rng(0).normal(100, 20, (64, 64))
    with pytest.raises(ValueError, match="target_noise"):
        advise_subset(img, target_noise=0)
    with pytest.raises(ValueError, match="ROI is empty|empty"):
        advise_subset(img, roi=np.zeros((64, 64), bool))
    with pytest.raises(ValueError, match="odd"):
        advise_subset(img, subsets=(20,))


def test_noise_floor_of_a_static_pair_removes_drift_and_measures_the_scatter():
    field = S.Translation(0.3, -0.2)  # the specimen drifted: no noise, no strain
    ref, dfm = S.speckle_pair((160, 160), field, noise=0.0, seed=3, bit_depth=None)
    nf = noise_floor(ref, dfm, subset=21, step=10)
    assert nf["drift_px"] == pytest.approx([0.3, -0.2], abs=0.01)
    assert nf["u_std_px"] < 0.01 and nf["v_std_px"] < 0.01
    assert max(nf["exx_std"], nf["eyy_std"], nf["exy_std"]) < 5e-4
    ref, dfm = S.speckle_pair((160, 160), field, noise=6.0, seed=3, bit_depth=None)
    noisy = noise_floor(ref, dfm, subset=21, step=10)
    res = correlate(ref, dfm, subset=21, step=10)
    predicted = np.median(res.u_std[res.valid])
    assert noisy["u_std_px"] == pytest.approx(predicted, rel=0.3)
    assert noisy["exx_std"] > 5 * nf["exx_std"]


def test_filter_gains_are_the_noise_statistics_of_the_gradients():
    from napari_aldic.engine.dic.quality import filter_gains

    rng = np.random.default_rng(3)
    noise = rng.normal(size=(512, 512))
    sigma = 0.6
    d = reference_gradients(prefilter(noise, 3))[0].astype(float)[8:-8, 8:-8]
    smooth = ndimage.gaussian_filter(noise, sigma, mode="reflect")
    dj = reference_gradients(prefilter(smooth, 3))[0].astype(float)[8:-8, 8:-8]
    g, g_j, c = filter_gains(sigma, 3)
    assert g == pytest.approx(d.var(), rel=0.02)
    assert g_j == pytest.approx(dj.var(), rel=0.03)
    assert c == pytest.approx(np.mean(d * dj), rel=0.03)
    assert g_j < 0.5 * g  # smoothing removes most of the gradient noise


def test_smoothed_jacobian_of_zero_width_is_the_plain_model():
    img, _ = S.speckle_pair((96, 96), S.Translation(0, 0), noise=3.0, seed=6)
    x = y = np.array([30, 48, 60])
    plain = speckle_quality(img, x, y, 21)
    gx, gy = reference_gradients(prefilter(img.astype(float), 3))
    same = speckle_quality(img, x, y, 21, jacobian=(gx, gy, 0.0))
    # the same up to the gain's two evaluations (impulse response vs. spectrum)
    np.testing.assert_allclose(static_uncertainty(same, 3.0), static_uncertainty(plain, 3.0),
                               rtol=1e-4)


def _covariance_by_numpy(q, var):
    """The model of ``node_uncertainty`` written out with np.linalg on the
    matrices of ``q``: ``2 σ² M⁻¹ (A - t E_A / 2) M⁻ᵀ`` at u and v."""
    k = q.hessian.shape[1] // 2
    a, ea = q.hessian, q.noise * var
    c, ec = (a, ea) if q.cross is None else (q.cross, q.cross_noise * var)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.diagonal(c, axis1=1, axis2=2) / np.diagonal(ec, axis1=1, axis2=2)
    t = np.minimum(0.9 * np.min(np.where(np.isfinite(r) & (r > 0), r, np.inf), axis=1), 1.0)
    spk = c - t[:, None, None] * ec
    out, cond = np.full((q.m.size, 2), np.nan), np.full(q.m.size, np.inf)
    for i in np.flatnonzero(q.m > 2 * k):  # (singular ones outside the ROI)
        cond[i] = np.linalg.cond(spk[i])
        if cond[i] < 1e12 and np.linalg.det(spk[i]) > 0:
            inv = np.linalg.inv(spk[i])
            cov = inv @ (a[i] - 0.5 * t[i] * ea[i]) @ inv.T
            out[i] = 2 * var * cov[0, 0], 2 * var * cov[k, k]
    return out, cond


@pytest.mark.filterwarnings("ignore:invalid value encountered in sqrt")
@pytest.mark.parametrize("shape_function", ["affine", "quadratic"])
@pytest.mark.parametrize("smoothed", [False, True])
def test_uncertainty_from_the_moments_is_the_matrix_model(shape_function, smoothed):
    """The uncertainty is computed from the window moments without building
    the matrices: it equals the model evaluated on the matrices (built on
    first access), with and without a ROI and smoothed steepest-descent
    images; assigning a matrix replaces it."""
    from napari_aldic.engine.dic.interpolation import steepest_descent_gradients

    img, _ = S.speckle_pair((160, 170), S.Translation(0, 0), noise=2.0, seed=8)
    img = img.astype(float)
    yy, xx = np.mgrid[:160, :170]
    roi = (xx - 85) ** 2 + (yy - 80) ** 2 < 70**2
    x, y = (a.ravel() for a in np.meshgrid(np.arange(10, 170, 9), np.arange(10, 160, 9)))
    jac = (*steepest_descent_gradients(img, 3, 0.8), 0.8) if smoothed else None
    for mask in (None, roi):
        q = speckle_quality(img, x, y, 21, mask, shape_function=shape_function, jacobian=jac)
        direct = static_uncertainty(q, 3.0) ** 2  # before any matrix exists
        want, cond = _covariance_by_numpy(q, 9.0)
        ok = cond < 1e9  # beyond, two solvers differ by more than 1e-9
        assert ok.sum() > 0.5 * x.size
        np.testing.assert_allclose(direct[ok], want[ok], rtol=1e-9)
        assert (q.cross is None) == (not smoothed)
        # once built, the matrices are used: the same numbers
        np.testing.assert_allclose(static_uncertainty(q, 3.0) ** 2, direct, rtol=1e-12)
        q.noise = 0.5 * q.noise
        half, _ = _covariance_by_numpy(q, 9.0)
        np.testing.assert_allclose(static_uncertainty(q, 3.0)[ok] ** 2, half[ok], rtol=1e-9)
        assert np.nanmax(np.abs(half[ok] / want[ok] - 1)) > 1e-3  # and it made a difference


def test_reading_the_matrices_keeps_the_moments_path(monkeypatch):
    """AL-DIC's propagation reads the speckle quality's matrices (gathered from
    the window moments); the Local uncertainty computed after that must still
    come straight from the moments (the flat matrix copy cost 0.07-0.13 s at
    15k nodes), with the same result. An assigned matrix switches to it."""
    import napari_aldic.engine.dic.quality as Q

    img, _ = S.speckle_pair((128, 128), S.Translation(0, 0), seed=3, bit_depth=None)
    x = y = np.array([40, 64, 88])
    seen = []
    real = Q.covariance_diag

    def spy(arrays, *args):
        seen.append(arrays)
        return real(arrays, *args)
    monkeypatch.setattr(Q, "covariance_diag", spy)
    q = speckle_quality(img, x, y, 31)
    before = static_uncertainty(q, 2.0)
    _ = (q.hessian, q.noise, q.cross, q.cross_noise)  # read, as the propagation does
    after = static_uncertainty(q, 2.0)
    np.testing.assert_array_equal(after, before)
    assert len(seen[1]) == len(q.sums.arrays)
    assert all(a is b or np.shares_memory(a, b) for a, b in zip(seen[1], q.sums.arrays))
    q.noise = 0.5 * q.noise  # assigned: the moments no longer describe it
    changed = static_uncertainty(q, 2.0)
    assert not any(np.shares_memory(a, q.sums.arrays[0]) for a in seen[2])
    assert np.all(np.abs(changed - before) > 1e-3 * before)  # the assignment counts
