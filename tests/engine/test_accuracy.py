"""Accuracy of Local DIC against exact synthetic truth."""

import numpy as np
import pytest

from napari_aldic.engine import Reason, correlate, synthetic as S


def _errors(res, field, mask=None):
    ut, vt = field.displacement(res.x, res.y)
    sel = res.valid if mask is None else res.valid & mask
    return res.u[sel] - ut[sel], res.v[sel] - vt[sel], sel


@pytest.mark.parametrize("shift", [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9])
def test_subpixel_translation_bias_and_rmse(shift):
    field = S.Translation(shift, -0.5 * shift)
    ref, dfm = S.speckle_pair((192, 192), field, seed=int(shift * 10))
    assert ref.dtype == np.uint8
    res = correlate(ref, dfm, subset=31, step=8)
    eu, ev, sel = _errors(res, field)
    assert sel.mean() > 0.95  # translation keeps every subset in view
    assert abs(eu.mean()) <= 0.005 and abs(ev.mean()) <= 0.005
    assert np.sqrt(np.mean(eu**2 + ev**2)) <= 0.01
    # gradients of a pure translation are zero
    assert np.abs(res.dudx[sel]).max() < 3e-3 and np.abs(res.dvdy[sel]).max() < 3e-3


@pytest.mark.parametrize("noise, tol_rmse", [(0.0, 0.01), (2.0, 0.03)])
def test_uniform_strain_and_rotation(noise, tol_rmse):
    field = S.Affine.strain_rotation(exx=0.01, eyy=0.01, angle_deg=1.0, center=(128, 128))
    ref, dfm = S.speckle_pair((256, 256), field, noise=noise, seed=5)
    res = correlate(ref, dfm, subset=31, step=8)
    eu, ev, sel = _errors(res, field)
    assert sel.sum() > 500
    assert np.sqrt(np.mean(eu**2 + ev**2)) <= tol_rmse
    G = np.asarray(field.G)
    for name, (i, j) in zip(("dudx", "dudy", "dvdx", "dvdy"), ((0, 0), (0, 1), (1, 0), (1, 1))):
        err = getattr(res, name)[sel] - G[i, j]
        assert abs(err.mean()) <= 5e-4, name
        if noise == 0:
            assert np.sqrt(np.mean(err**2)) <= 5e-4, name
    # nodes flagged only because their deformed subset leaves the image
    flagged = res.reason[~res.valid]
    assert set(np.unique(flagged)) <= {Reason.OUT_OF_IMAGE}


def test_sinusoidal_field_follows_truth():
    field = S.Sinusoid(amplitude_u=0.8, amplitude_v=0.5, wavelength=160.0)
    ref, dfm = S.speckle_pair((256, 256), field, seed=8)
    res = correlate(ref, dfm, subset=31, step=8)
    eu, ev, sel = _errors(res, field)
    assert sel.mean() > 0.9
    # A first-order subset of width S sees the sinusoid averaged over the
    # subset: amplitude scaled by the discrete box response
    # sin(S k / 2) / (S sin(k / 2)) (~0.94 here, i.e. 0.048 px lost at peaks).
    k = 2 * np.pi / field.wavelength
    atten = np.sin(31 * k / 2) / (31 * np.sin(k / 2))
    ut, vt = field.displacement(res.x, res.y)
    du = res.u[sel] - atten * ut[sel]
    dv = res.v[sel] - atten * vt[sel]
    assert np.sqrt(np.mean(du**2 + dv**2)) <= 0.01
    # the attenuation is real: against the raw truth the error is larger
    assert np.sqrt(np.mean(eu**2 + ev**2)) > 0.02


def test_large_translation_found_by_initial_guess():
    field = S.Translation(37.4, -12.3)
    ref, dfm = S.speckle_pair((256, 256), field, seed=11)
    res = correlate(ref, dfm, subset=31, step=8, search=16)
    eu, ev, sel = _errors(res, field)
    # every node whose deformed subset stays inside the image is recovered
    inside = (res.x + 37.4 + 15 <= 255) & (res.y - 12.3 - 15 >= 0)
    assert res.valid[inside].mean() > 0.97
    assert np.abs(eu).max() < 0.02 and np.abs(ev).max() < 0.02
    # and nodes whose material leaves the view are not reported as valid
    assert not np.any(res.valid & ~inside & (res.x + 37.4 + 15 > 256))


def _crack_case():
    shape = (256, 320)
    tip = (200.0, 128.0)
    field = S.ModeICrack(tip=tip, amplitude=0.08, t=(0.3, 0.2))
    ref, dfm = S.speckle_pair(shape, field, seed=21)
    roi = np.ones(shape, bool)
    roi[127:130, : int(tip[0]) + 1] = False  # the crack: a 3-px slot up to the tip
    return field, ref, dfm, roi


def test_crack_faces_are_not_smeared():
    field, ref, dfm, roi = _crack_case()
    assert field.opening(100.0) > 4.0  # faces open by several pixels
    res = correlate(ref, dfm, roi=roi, subset=31, step=4)
    # nodes whose subsets are cut by the crack, away from the tip region
    near = (np.abs(res.y - 128) <= 16) & (res.x < 170)
    upper = near & (res.y < 128)
    lower = near & (res.y > 128)
    eu, ev, sel = _errors(res, field, near)
    assert res.valid[near].mean() > 0.97
    assert np.abs(eu).max() < 0.03 and np.abs(ev).max() < 0.03
    # each face moves its own way: v differs by the opening across the crack
    assert res.v[upper & res.valid].mean() < -1.0
    assert res.v[lower & res.valid].mean() > 1.0
    # without the mask the same nodes straddle the crack and go wrong or get flagged
    plain = correlate(ref, dfm, subset=31, step=4)
    near_p = (np.abs(plain.y - 128) <= 16) & (plain.x < 170)
    ut, vt = field.displacement(plain.x, plain.y)
    wrong = np.hypot(plain.u - ut, plain.v - vt) > 0.03
    assert np.count_nonzero(near_p & (wrong | ~plain.valid)) > 0.5 * near_p.sum()


def test_small_component_nodes_are_flagged():
    field = S.Translation(0.3, 0.2)
    ref, dfm = S.speckle_pair((192, 192), field, seed=4)
    roi = np.ones(ref.shape, bool)
    # a 10-px ligament of material between two masked bands (rows 90..99)
    roi[70:90, :] = False
    roi[100:120, :] = False
    res = correlate(ref, dfm, roi=roi, subset=31, step=4)
    lig = (res.y >= 90) & (res.y <= 99)
    assert lig.sum() > 10
    assert np.all(res.reason[lig] == Reason.SMALL_COMPONENT)
    assert not res.valid[lig].any()
    # nodes outside the ligament with enough material stay accurate
    eu, ev, sel = _errors(res, field)
    assert sel.sum() > 200 and np.abs(eu).max() < 0.02 and np.abs(ev).max() < 0.02


def test_quintic_interpolation_also_accurate():
    field = S.Translation(0.35, 0.65)
    ref, dfm = S.speckle_pair((160, 160), field, seed=2)
    res = correlate(ref, dfm, interpolation="quintic")
    eu, ev, sel = _errors(res, field)
    assert sel.mean() > 0.95 and np.sqrt(np.mean(eu**2 + ev**2)) <= 0.01


def test_sixteen_bit_and_float_inputs_agree_with_eight_bit():
    field = S.Translation(0.45, 0.15)
    pat = S.make_pattern((160, 160), seed=9)
    r16 = S.render(pat, (160, 160), None, bit_depth=16)
    d16 = S.render(pat, (160, 160), field, bit_depth=16)
    assert r16.dtype == np.uint16 and r16.max() > 10000
    a = correlate(r16, d16)
    b = correlate(r16.astype(np.float64) / 65535.0, d16.astype(np.float64) / 65535.0)
    eu, ev, sel = _errors(a, field)
    assert np.sqrt(np.mean(eu**2 + ev**2)) <= 0.005
    np.testing.assert_allclose(a.u, b.u, atol=1e-4)


def test_auto_interpolation_handles_fine_speckle():
    from scipy import ndimage

    rng = np.random.default_rng(5)
    n = 192
    base = ndimage.gaussian_filter(rng.random((n, n)), 0.8)
    base = (base - base.min()) / (base.max() - base.min()) * 200 + 20
    F = np.fft.fft2(base)
    ky = np.fft.fftfreq(n)[:, None]
    kx = np.fft.fftfreq(n)[None, :]
    shift = 0.3
    # an exact sub-pixel shift of a band-limited pattern (Fourier phase ramp)
    dfm = np.real(np.fft.ifft2(F * np.exp(-2j * np.pi * (kx * shift + ky * shift))))
    ref8, dfm8 = np.round(base).astype(np.uint8), np.round(dfm).astype(np.uint8)
    auto = correlate(ref8, dfm8)
    cubic = correlate(ref8, dfm8, interpolation="cubic")
    assert auto.meta["interpolation"] == "quintic"
    inner = lambda r: r.valid & (r.x > 30) & (r.x < 160) & (r.y > 30) & (r.y < 160)  # noqa: E731
    bias_auto = abs(auto.u[inner(auto)].mean() - shift)
    bias_cubic = abs(cubic.u[inner(cubic)].mean() - shift)
    assert bias_auto <= 0.005
    assert bias_auto < 0.6 * bias_cubic
    # ordinary speckle keeps the faster cubic splines
    ref, dfm = S.speckle_pair((128, 128), S.Translation(0.3, 0.1), seed=1)
    assert correlate(ref, dfm).meta["interpolation"] == "cubic"
