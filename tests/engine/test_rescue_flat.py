"""The repair stage leaves nodes whose reference subset is flat alone: they are
NO_TEXTURE before any IC-GN step from every start, so retrying or searching them
cannot change them (on the shipped crack sequence, a saturated region made each
frame's own-node searches widen to the largest range: 24-30 s of 25-31 s)."""

import numpy as np

from napari_aldic.engine import Reason, correlate, synthetic


def _pair_with_a_saturated_band():
    f = synthetic.Affine.strain_rotation(exx=0.004, center=(128, 128), t=(1.3, -0.6))
    r, d = synthetic.speckle_pair((256, 256), f, noise=0.5, seed=3)
    r[:, 160:] = 255  # saturated in both images: no texture at all
    d[:, 160:] = 255
    return f, r, d


def test_flat_reference_subsets_are_not_searched_again():
    f, r, d = _pair_with_a_saturated_band()
    res = correlate(r, d, subset=31, step=8)
    flat = res.x - 15 >= 160  # subsets wholly in the saturated band
    assert flat.sum() >= 40
    assert np.all(res.reason[flat] == Reason.NO_TEXTURE) and not res.valid[flat].any()
    # before: every flat node was retried and searched (up to the widest range)
    assert res.meta["timing"]["rescue_searches"] < 0.1 * flat.sum()
    assert res.meta["timing"]["rescue_nodes"] < 0.1 * flat.sum()
    # the speckled part is measured as before
    moving = res.x + 15 < 160
    ut, vt = f.displacement(res.x, res.y)
    err = np.hypot(res.u - ut, res.v - vt)
    assert res.valid[moving].mean() > 0.9
    assert np.all(err[res.valid] < 0.05)
