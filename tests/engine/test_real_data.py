"""Real speckle images (no ground truth: physical checks).

The crack sequence is optional data next to the repository (``../shared/data``, see the
``shared_data`` fixture): without it that test is skipped with the reason. The open-hole
images ship with the repository (``sample_data/``).
"""

import numpy as np
import pytest
import tifffile

from napari_aldic.engine import correlate, track


@pytest.fixture(scope="module")
def crack_stack(shared_data):
    path = shared_data / "crack_sequence" / "crack_sequence.tif"
    if not path.is_file():
        pytest.skip(f"optional real data not found: {path}")
    return path


@pytest.mark.slow  # ~9 s
def test_real_crack_sequence_opens_across_the_masked_crack(crack_stack):
    roi = np.zeros((1228, 800), bool)
    roi[30:1100, 262:790] = True  # the speckled specimen
    roi[596:606, 262:330] = False  # the crack growing from the notch
    seq = track(crack_stack, roi=roi, subset=31, step=8, frames=[0, 2, 4, 6, 8, 10])
    assert len(seq) == 6 and seq.complete
    last = seq[5]
    assert last.valid.mean() > 0.9
    band = (last.y >= 576) & (last.y < 596), (last.y > 606) & (last.y <= 626)
    near = [last.valid & b & (last.x < 300) for b in band]
    far = [last.valid & b & (last.x > 600) for b in band]
    assert near[0].sum() >= 8 and near[1].sum() >= 8
    # the faces next to the notch move apart by pixels (upper face up: v more negative)
    opening = last.v[near[1]].mean() - last.v[near[0]].mean()
    assert opening > 2.0
    # far from the crack the same rows move together (continuous field)
    assert abs(last.v[far[1]].mean() - last.v[far[0]].mean()) < 0.5
    # the whole specimen also moves ~56 px up between frames 0 and 10
    assert -60 < np.median(last.v[last.valid]) < -52


def test_whole_pixel_shift_of_a_real_image_is_exact(repo_root):
    img = tifffile.imread(repo_root / "sample_data" / "open_hole_tension" / "oht_cfrp_00.tiff")
    ref = img[100:500, 50:350]
    dfm = img[103:503, 45:345]  # material at X appears at X + (5, -3)
    res = correlate(ref, dfm, subset=31, step=10)
    v = res.valid
    assert v.mean() > 0.9
    assert np.abs(res.u[v] - 5).max() < 0.01
    assert np.abs(res.v[v] + 3).max() < 0.01
