"""Seed-propagation initial guess."""

import numpy as np
import pytest

from napari_aldic.engine import correlate, synthetic as S


@pytest.fixture(scope="module")
def far_moved():
    # 150 px rigid motion plus 5 % stretch: far beyond the FFT search range
    field = S.Affine.strain_rotation(exx=0.05, eyy=0.0, center=(100, 160), t=(150.0, 6.0))
    ref, dfm = S.speckle_pair((320, 448), field, seed=17, n_quad=3, margin=220)
    roi = np.zeros(ref.shape, bool)
    roi[20:300, 20:260] = True  # material that stays in view
    return field, ref, dfm, roi


def test_seeds_solve_motion_beyond_fft_range(far_moved):
    field, ref, dfm, roi = far_moved
    res = correlate(ref, dfm, roi=roi, init="seeds", seeds=[(120, 160)], step=8)
    ut, vt = field.displacement(res.x, res.y)
    inside = (res.x + ut + 16 < 447) & (res.x + ut - 16 > 0)
    assert res.valid[inside].mean() > 0.97
    v = res.valid
    assert np.abs(res.u[v] - ut[v]).max() < 0.03
    assert np.abs(res.v[v] - vt[v]).max() < 0.03
    # the FFT guess with its default range cannot find this motion
    fft = correlate(ref, dfm, roi=roi, init="fft", step=8, search=20, search_max=80)
    ok = fft.valid & (np.hypot(fft.u - ut, fft.v - vt) < 0.05)
    assert ok.mean() < 0.5


def test_seed_outside_roi_is_an_error(far_moved):
    _, ref, dfm, roi = far_moved
    with pytest.raises(ValueError, match=r"seed \(400, 10\) is outside the ROI"):
        correlate(ref, dfm, roi=roi, init="seeds", seeds=[(400, 10)])


def test_region_without_seed_is_named():
    ref, dfm = S.speckle_pair((160, 200), S.Translation(0.3, 0.2), seed=3)
    roi = np.zeros(ref.shape, bool)
    roi[10:150, 10:90] = True
    roi[10:150, 110:190] = True  # a second, separate region
    with pytest.raises(ValueError, match=r"ROI region 2 \(x 110-189, y 10-149"):
        correlate(ref, dfm, roi=roi, init="seeds", seeds=[(50, 80)])
    res = correlate(ref, dfm, roi=roi, init="seeds", seeds=[(50, 80), (150, 80)])
    assert res.valid.mean() > 0.9
    assert np.abs(res.u[res.valid] - 0.3).max() < 0.02


def test_seeds_parameter_validation():
    ref, dfm = S.speckle_pair((96, 96), S.Translation(0.3, 0.2), seed=3)
    with pytest.raises(ValueError, match="at least one seed"):
        correlate(ref, dfm, init="seeds")
