"""Large, spatially varying motion: the anchored initial guess (issue 13, section 1).

Exact truth from ``napari_aldic.engine.synthetic``. Every measurable node
(its deformed subset inside the image, by the truth) must be valid and
accurate, and the repair stage must stay the exception: the diagnostics in
``meta["timing"]`` count the nodes it had to retry and search on their own.
"""

from __future__ import annotations

import numpy as np
import pytest

from napari_aldic.engine import DICParams, correlate, synthetic

TOL_PX = 0.05  # noise-free 8-bit speckle: errors are a few hundredths at most


def _measurable(res, field, half, margin=3):
    """Nodes whose deformed subset (its four corners, by the truth) lies
    inside the image with ``margin`` px for the interpolation."""
    rows, cols = res.image_shape
    ok = res.reason != 1  # 1: SMALL_COMPONENT (mask), never measurable
    for dx in (-half, half):
        for dy in (-half, half):
            cu, cv = field.displacement(res.x + dx, res.y + dy)
            xd, yd = res.x + dx + cu, res.y + dy + cv
            ok &= (xd >= margin) & (xd <= cols - 1 - margin)
            ok &= (yd >= margin) & (yd <= rows - 1 - margin)
    ut, vt = field.displacement(res.x, res.y)
    return ok, ut, vt


def _check(res, field, half=15):
    meas, ut, vt = _measurable(res, field, half)
    err = np.hypot(res.u - ut, res.v - vt)
    assert meas.sum() > 0.5 * len(res)
    assert res.valid[meas].all(), f"{(~res.valid[meas]).sum()} measurable nodes not valid"
    assert err[res.valid].max() < TOL_PX, err[res.valid].max()
    return res.meta["timing"]


@pytest.fixture(scope="module")
def translation_strain():
    field = synthetic.Affine.strain_rotation(exx=0.03, eyy=-0.01, center=(256, 256),
                                             t=(40.0, -12.5))
    ref, dfm = synthetic.speckle_pair((512, 512), field, seed=11, n_quad=2, margin=80)
    return field, ref, dfm


def test_translation_40px_with_strain_all_valid_little_rescue(translation_strain):
    field, ref, dfm = translation_strain
    res = correlate(ref, dfm, subset=31, step=8)
    t = _check(res, field)
    # the anchored guess ran; the two anchors at x = 400 (44 px motion) take a
    # chance peak and fail, and their coarse nodes are predicted from the others
    assert t["anchors"] >= 2
    # the guess was right nearly everywhere: only nodes at the image edge,
    # whose material is leaving the view, go through the repair stage
    assert t["rescue_nodes"] <= 0.02 * len(res)
    assert t["rescue_searches"] <= 0.005 * len(res)


def test_anchors_off_gives_the_same_field(translation_strain):
    field, ref, dfm = translation_strain
    new = correlate(ref, dfm, subset=31, step=8)
    old = correlate(ref, dfm, subset=31, step=8, anchor_spacing=0)
    assert old.meta["timing"]["anchors"] == 0
    _check(old, field)
    both = new.valid & old.valid
    assert np.array_equal(new.valid, old.valid)
    assert np.abs(new.u[both] - old.u[both]).max() < 1e-3
    assert np.abs(new.v[both] - old.v[both]).max() < 1e-3


@pytest.mark.parametrize("field, shape, seed, n_quad, step", [
    # a 10 degree rotation
    (synthetic.Affine.strain_rotation(angle_deg=10.0, center=(256, 256)), (512, 512), 12, 2,
     8),
    # 5 % stretch and 2 degrees: the motion varies by 51 px across the image
    # and exceeds the first search range (20 px) at the edges
    (synthetic.Affine.strain_rotation(exx=0.05, eyy=0.02, angle_deg=2.0, center=(200, 300),
                                      t=(6.0, 3.0)), (1024, 1024), 13, 1, 16),
], ids=["rotation_10_degrees", "spatially_varying_5_percent_strain"])
def test_anchors_make_rescue_the_exception(field, shape, seed, n_quad, step):
    ref, dfm = synthetic.speckle_pair(shape, field, seed=seed, n_quad=n_quad, margin=96)
    res = correlate(ref, dfm, subset=31, step=step)
    t = _check(res, field)
    assert t["anchors"] >= 4
    assert t["rescue_nodes"] <= 0.02 * len(res)
    assert t["rescue_searches"] <= 0.005 * len(res)


def test_anchor_spacing_is_validated():
    with pytest.raises(ValueError, match="anchor_spacing"):
        DICParams(anchor_spacing=-1)
    assert DICParams(anchor_spacing=0).resolved_anchor_spacing() == 0
    p = DICParams(subset=31, step=8)  # coarse spacing 64
    assert p.resolved_anchor_spacing() == 256
    assert DICParams(anchor_spacing=200).resolved_anchor_spacing() == 192


def test_coarse_nodes_search_8px_around_the_prediction_first(translation_strain, monkeypatch):
    """The coarse nodes centred on their anchors' prediction search ±8 px first
    (``PREDICTED_SEARCH``, an FFT of 48² instead of 72²), the anchors the
    full ``search``; the result is the same as with the full first range."""
    import napari_aldic.engine.dic.local as L

    field, ref, dfm = translation_strain
    ranges = []
    real = L.ncc_search_widening

    def spy(f, g, xs, ys, half, search, *a, **k):
        ranges.append((xs.size, search, k.get("cu") is not None))
        return real(f, g, xs, ys, half, search, *a, **k)
    monkeypatch.setattr(L, "ncc_search_widening", spy)
    res = correlate(ref, dfm, subset=31, step=8)
    anchors, coarse = ranges[0], ranges[1]
    assert anchors[1] == 20 and not anchors[2]
    assert coarse[1] == L.PREDICTED_SEARCH == 8 and coarse[2] and coarse[0] > 4 * anchors[0]
    monkeypatch.setattr(L, "PREDICTED_SEARCH", 20)
    wide = correlate(ref, dfm, subset=31, step=8)
    assert np.array_equal(res.valid, wide.valid)
    assert np.abs(res.u - wide.u)[res.valid].max() < 1e-4
    assert np.abs(res.v - wide.v)[res.valid].max() < 1e-4
