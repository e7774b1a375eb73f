"""A valid node is a promise: hard cases never report a wrong value as valid.

Every scenario is a seeded synthetic speckle pair with exact truth (issue 11).
"Wrong" means off by more than 0.5 px; "measurable" nodes are those whose
whole deformed subset lies in the deformed image (by the truth), so only they
can be measured at all.
"""

import numpy as np
import pytest

from napari_aldic.engine import Reason, correlate, synthetic as S
from napari_aldic.engine.core.params import DICParams
from napari_aldic.engine.dic.reliability import (
    MISMATCH_ALLOWANCE,
    NOISE_CAP,
    SubsetStats,
    Validity,
    image_noise,
)

WRONG_PX = 0.5
FLAGS = {Reason.POOR_MATCH, Reason.BEYOND_SEARCH, Reason.UNCERTAIN, Reason.GLOBAL_MISMATCH}


def _check(res, field, dfm_shape, roi=None):
    """``(wrong valid nodes, measurable nodes, fraction of them valid)``."""
    ut, vt = field.displacement(res.x, res.y)
    err = np.hypot(res.u - ut, res.v - vt)
    wrong = res.valid & ~(err <= WRONG_PX)
    h = res.params.half
    inside = np.ones(len(res), bool)
    for dx in (-h, h):
        for dy in (-h, h):
            du, dv = field.displacement(res.x + dx, res.y + dy)
            xx, yy = res.x + dx + du, res.y + dy + dv
            inside &= ((xx >= 1) & (yy >= 1) & (xx <= dfm_shape[1] - 2)
                       & (yy <= dfm_shape[0] - 2))
    if roi is not None:
        inside &= roi[res.y.astype(int), res.x.astype(int)]
    frac = float(res.valid[inside].mean()) if inside.any() else 1.0
    return int(wrong.sum()), inside, frac


# ----------------------------------------------------------------- hard cases
@pytest.mark.parametrize("noise", [0.0, 10.0])
def test_motion_beyond_the_search_range_is_never_valid(noise):
    # 60 px shift, search limited to 30 px: every node's best match is spurious
    field = S.Translation(60.0, 0.0)
    ref, dfm = S.speckle_pair((192, 192), field, seed=5, margin=100, noise=noise)
    res = correlate(ref, dfm, subset=31, step=8, search=20, search_max=30)
    wrong, inside, _ = _check(res, field, dfm.shape)
    assert wrong == 0
    assert not res.valid.any()
    # flagged with a reason that says why: no match within the range
    codes = set(np.unique(res.reason[inside]).tolist())
    assert codes & {Reason.BEYOND_SEARCH, Reason.POOR_MATCH}


def test_translation_beyond_the_default_range():
    field = S.Translation(120.0, 0.0)  # default search_max: 80 px on 256^2
    ref, dfm = S.speckle_pair((256, 256), field, seed=6, margin=160)
    res = correlate(ref, dfm, subset=31, step=8)
    assert _check(res, field, dfm.shape)[0] == 0
    assert not res.valid.any()


@pytest.mark.parametrize("method", ["local", "aldic"])
def test_unrelated_images_give_no_valid_node(method):
    ref = S.speckle_pair((128, 128), None, seed=1)[0]
    dfm = S.speckle_pair((128, 128), None, seed=7)[0]
    res = correlate(ref, dfm, subset=31, step=8, method=method)
    assert not res.valid.any()


@pytest.mark.parametrize("angle, method", [(30, "local"), (45, "local"), (-45, "local"),
                                           (90, "local"), (45, "aldic")])
def test_large_rotations_are_measured(angle, method):
    # a plain cross-correlation finds nothing beyond ~25 deg; the rotated
    # search at a few nodes and the propagation of full warps measure them
    field = S.Affine.strain_rotation(angle_deg=angle, center=(96, 96))
    ref, dfm = S.speckle_pair((192, 192), field, noise=1.0, seed=10 + abs(angle), margin=90)
    res = correlate(ref, dfm, subset=31, step=8, method=method)
    wrong, inside, frac = _check(res, field, dfm.shape)
    assert wrong == 0
    assert frac >= 0.95
    ut, vt = field.displacement(res.x, res.y)
    assert np.abs(np.hypot(res.u - ut, res.v - vt)[res.valid]).max() < 0.05


def test_seeds_propagate_through_45_degrees():
    field = S.Affine.strain_rotation(angle_deg=45, center=(96, 96))
    ref, dfm = S.speckle_pair((192, 192), field, noise=1.0, seed=72, margin=90)
    res = correlate(ref, dfm, subset=31, step=8, init="seeds", seeds=[(60, 130)])
    wrong, inside, frac = _check(res, field, dfm.shape)
    assert wrong == 0 and frac >= 0.95


@pytest.mark.parametrize("method", ["local", "aldic"])
def test_heavy_noise_flags_uncertain_nodes_instead_of_reporting_them(method):
    field = S.Affine.strain_rotation(exx=0.01, center=(80, 80), t=(1.3, -0.4))
    ref, dfm = S.speckle_pair((160, 160), field, noise=40.0, seed=90)
    res = correlate(ref, dfm, subset=31, step=8, method=method)
    assert _check(res, field, dfm.shape)[0] == 0
    assert np.count_nonzero(res.reason == Reason.UNCERTAIN) > 0.2 * len(res)
    if method == "local":
        # without the uncertainty test nodes off by 3x max_uncertainty (0.1 px)
        # pass as trusted (over 0.5 px before the noise-chosen smoothing of
        # the steepest-descent images, section 5.1 of docs/method.md)
        loose = correlate(ref, dfm, subset=31, step=8, max_uncertainty=None)
        ut, vt = field.displacement(loose.x, loose.y)
        assert np.hypot(loose.u - ut, loose.v - vt)[loose.valid].max() > 0.3


def test_moderate_noise_keeps_its_correct_matches():
    # ZNCC ~0.9 here: a correct match is not rejected for a ZNCC that the
    # image noise explains
    field = S.Affine.strain_rotation(exx=0.01, center=(80, 80), t=(1.3, -0.4))
    ref, dfm = S.speckle_pair((160, 160), field, noise=20.0, seed=60)
    res = correlate(ref, dfm, subset=31, step=8)
    wrong, inside, frac = _check(res, field, dfm.shape)
    assert wrong == 0 and frac >= 0.95
    assert np.median(res.zncc[res.valid]) < 0.93


def test_aldic_does_not_vouch_for_a_field_smoothed_across_an_unmasked_crack():
    field = S.ModeICrack(tip=(150.0, 128.0), amplitude=0.25)
    ref, dfm = S.speckle_pair((256, 256), field, seed=9)
    res = correlate(ref, dfm, subset=31, step=8, method="aldic")
    assert _check(res, field, dfm.shape)[0] == 0
    flagged = res.reason == Reason.GLOBAL_MISMATCH
    assert flagged.sum() > 10
    # those nodes' own (local) matches were right: AL-DIC moved them
    ut, vt = field.displacement(res.x, res.y)
    assert np.median(np.hypot(res.u_local - ut, res.v_local - vt)[flagged]) < 0.1


# ----------------------------------------------------------------- easy cases
@pytest.mark.parametrize("case", ["translation", "strain", "rotation"])
def test_easy_cases_keep_their_valid_nodes(case):
    field, margin = {
        "translation": (S.Translation(7.3, -4.6), 64),
        "strain": (S.Affine.strain_rotation(exx=0.10, center=(96, 96)), 64),
        "rotation": (S.Affine.strain_rotation(angle_deg=20, center=(96, 96)), 90),
    }[case]
    ref, dfm = S.speckle_pair((192, 192), field, noise=2.0, seed=21, margin=margin)
    res = correlate(ref, dfm, subset=31, step=8)
    wrong, inside, frac = _check(res, field, dfm.shape)
    assert wrong == 0 and frac >= 0.95


# ----------------------------------------------------------------- the tests themselves
@pytest.mark.parametrize("noise", [5.0, 20.0])
def test_image_noise_is_estimated_from_one_image(noise):
    img = S.speckle_pair((256, 256), None, noise=noise, seed=3)[0]
    assert image_noise(img) == pytest.approx(noise, rel=0.1)
    # only the ROI counts: a flat background outside it does not lower it
    img2 = img.copy()
    img2[:, 128:] = 100
    roi = np.zeros(img.shape, bool)
    roi[:, :128] = True
    assert image_noise(img2, roi) == pytest.approx(noise, rel=0.1)
    assert image_noise(img2) < 0.8 * noise


def test_clean_speckle_has_a_small_noise_estimate():
    img = S.speckle_pair((256, 256), None, seed=3)[0]
    assert image_noise(img) < 1.0  # 8-bit rounding (0.29 GL) plus fine texture


def _validity(var_f, image_var, **params):
    n = var_f.size
    table = np.column_stack([np.full(n, 961.0), var_f, np.full(n, 4e5), np.zeros(n),
                             np.full(n, 4e5)])
    return Validity(SubsetStats(table), image_var, 1.4, DICParams(**params))


def test_reference_residual_ignores_a_majority_of_spurious_matches():
    var_f = np.full(100, 3000.0)
    zncc = np.full(100, 0.65)  # spurious matches: residual 1050 GL^2
    zncc[:10] = 0.9999  # a few correct ones on a clean image (0.3 GL^2)
    v = _validity(var_f, image_var=0.3)
    assert v.level(zncc, np.ones(100, bool)) == pytest.approx(NOISE_CAP * 0.3)
    floor = v.zncc_floor(zncc, np.ones(100, bool))
    assert np.all(zncc[10:] < floor[10:]) and np.all(zncc[:10] >= floor[:10])
    assert floor[0] == pytest.approx(1 - MISMATCH_ALLOWANCE - 3 * 0.6 / 3000)


def test_noisy_images_lower_the_correlation_floor_and_the_test_can_be_disabled():
    var_f = np.full(50, 3000.0)
    zncc = np.full(50, 0.7)  # residual 900 GL^2: 30 GL of noise
    v = _validity(var_f, image_var=900.0)
    assert np.all(zncc >= v.zncc_floor(zncc, np.ones(50, bool)))
    assert np.all(v.zncc_floor(zncc, np.ones(50, bool)) == 0.6)  # zncc_min
    w = _validity(var_f, image_var=1.0, zncc_rel=0.0)
    assert np.all(w.zncc_floor(np.full(50, 0.7), np.ones(50, bool)) == 0.6)


def test_new_reason_codes_are_described():
    for code in FLAGS:
        assert "unknown" not in Reason.describe(code)
    assert Reason.describe(Reason.BEYOND_SEARCH) == "motion beyond the search range"


def test_max_uncertainty_is_validated():
    with pytest.raises(ValueError, match="max_uncertainty"):
        DICParams(max_uncertainty=0.0)
    with pytest.raises(ValueError, match="max_uncertainty"):
        DICParams(max_uncertainty="0.1")
    assert DICParams(max_uncertainty=None).max_uncertainty is None
