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


def test_widening_search_settles_flat_subsets_without_searching_wider(monkeypatch):
    """A flat subset has no valid shift at any range: the widening search gives
    it the widest range's verdict (no peak, range = search_max) without FFTs at
    every doubling (18 s per crack frame before), and leaves the others as they
    were (a node whose motion is beyond the first range is still found)."""
    from napari_aldic.engine.dic import init_guess

    f, r, d = _pair_with_a_saturated_band()
    r, d = r.astype(np.float32), d.astype(np.float32)
    d = np.roll(d, (0, 30), axis=(0, 1))  # the speckle moves 30 px: beyond ±20
    xs = np.array([60, 80, 220, 230])
    ys = np.array([100, 140, 100, 150])  # the last two in the saturated band
    searched = []
    real = init_guess.ncc_search

    def spy(f_, g_, xs_, ys_, half, R, *a, **k):
        searched.append((R, set(zip(xs_.tolist(), ys_.tolist()))))
        return real(f_, g_, xs_, ys_, half, R, *a, **k)

    monkeypatch.setattr(init_guess, "ncc_search", spy)
    res = init_guess.ncc_search_widening(r, d, xs, ys, 15, 20, 80, accept=0.5)
    assert [R for R, _ in searched] == [20, 40]  # the moving nodes need one doubling
    assert all((220, 100) not in nodes and (230, 150) not in nodes for _, nodes in searched[1:])
    assert np.all(np.isnan(res.peak[2:])) and np.all(res.search[2:] == 80)
    assert np.all(res.u[2:] == 0) and not res.on_border[2:].any()
    ut, vt = f.displacement(xs[:2], ys[:2])
    assert np.all(res.peak[:2] > 0.95) and np.all(res.search[:2] == 40)
    assert np.all(np.abs(res.u[:2] - 30 - ut) < 0.1) and np.all(np.abs(res.v[:2] - vt) < 0.1)
