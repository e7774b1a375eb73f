"""Bad inputs raise clear errors; odd-but-valid inputs are handled."""

import numpy as np
import pytest

from napari_aldic.engine import DICParams, correlate, synthetic as S


@pytest.fixture(scope="module")
def pair():
    return S.speckle_pair((128, 128), S.Translation(0.4, 0.2), seed=1)


def test_mismatched_shapes(pair):
    ref, dfm = pair
    with pytest.raises(ValueError, match=r"shape \(128, 128\) differs .* \(128, 120\)"):
        correlate(ref, dfm[:, :120])


def test_empty_roi(pair):
    ref, dfm = pair
    with pytest.raises(ValueError, match="ROI mask is empty"):
        correlate(ref, dfm, roi=np.zeros(ref.shape, bool))


def test_roi_of_wrong_shape(pair):
    ref, dfm = pair
    with pytest.raises(ValueError, match="ROI mask shape"):
        correlate(ref, dfm, roi=np.ones((10, 10), bool))


@pytest.mark.parametrize("which", ["reference", "deformed"])
def test_blank_image(pair, which):
    ref, dfm = pair
    blank = np.full_like(ref, 77)
    args = (blank, dfm) if which == "reference" else (ref, blank)
    with pytest.raises(ValueError, match=f"{which} image is blank"):
        correlate(*args)


def test_nan_pixels(pair):
    ref, dfm = pair
    bad = dfm.astype(np.float32)
    bad[5, 7] = np.nan
    with pytest.raises(ValueError, match="1 NaN or infinite pixel"):
        correlate(ref, bad)


def test_subset_larger_than_roi(pair):
    ref, dfm = pair
    roi = np.zeros(ref.shape, bool)
    roi[50:70, 50:70] = True  # 20 x 20 region, subset 31
    with pytest.raises(ValueError, match="subset=31 px is too large for the ROI"):
        correlate(ref, dfm, roi=roi, subset=31, step=4)


def test_subset_larger_than_image():
    ref, dfm = S.speckle_pair((24, 40), S.Translation(0.2, 0.1))
    with pytest.raises(ValueError, match="larger than the image"):
        correlate(ref, dfm, subset=31)


def test_not_2d(pair):
    ref, dfm = pair
    with pytest.raises(ValueError, match="2-D greyscale"):
        correlate(np.stack([ref, ref]), np.stack([dfm, dfm]))


def test_bool_image_rejected(pair):
    ref, dfm = pair
    with pytest.raises(ValueError, match="dtype bool"):
        correlate(ref > 100, dfm > 100)


@pytest.mark.parametrize(
    "kwargs, text",
    [
        ({"subset": 30}, "odd full width"),
        ({"subset": 5}, "odd full width"),
        ({"step": 0}, "step=0"),
        ({"method": "global"}, "method='global'"),
        ({"tol": 0.0}, "tol=0.0"),
        ({"search": 0}, "search=0"),
        ({"zncc_min": 1.5}, "zncc_min=1.5"),
        ({"interpolation": "linear"}, "interpolation='linear'"),
        ({"step": 2.5}, "step=2.5 must be an integer"),
    ],
)
def test_invalid_parameters(kwargs, text):
    with pytest.raises(ValueError, match=text):
        DICParams(**kwargs)


def test_unknown_parameter_in_dict():
    with pytest.raises(ValueError, match=r"Unknown DIC parameter\(s\) \['subsetsize'\]"):
        DICParams.from_dict({"subsetsize": 31})


def test_rgb_is_converted_with_warning(pair):
    ref, dfm = pair
    rgb_r = np.repeat(ref[..., None], 3, axis=2)
    rgb_d = np.repeat(dfm[..., None], 3, axis=2)
    with pytest.warns(UserWarning, match="RGB"):
        res = correlate(rgb_r, rgb_d)
    grey = correlate(ref, dfm)
    np.testing.assert_allclose(res.u, grey.u, atol=1e-4)


def test_params_object_and_overrides(pair):
    ref, dfm = pair
    p = DICParams(subset=21, step=10)
    res = correlate(ref, dfm, params=p)
    assert res.params.subset == 21 and res.params.step == 10
    res2 = correlate(ref, dfm, params=p, step=6)
    assert res2.params.step == 6 and res2.params.subset == 21
    assert len(res2) > len(res)
