"""Static features and periodic texture never pass as valid (issue 22).

Three traps on a 256² speckle pair (exx 0.5 %, shift (1.3, -0.6) px): the left
half black in both images, a 16 px dark bar fixed in both images, and a periodic
pattern (period 6 px) shifted by 4.2 px. For Local DIC and AL-DIC: no valid node
off by more than 0.5 px, at least 90 % of the nodes whose subset lies wholly in
moving speckle still valid, and an honest, finite ``u_std``/``v_std`` at every
valid node (at most ``max_uncertainty``). Clean speckle, moving or not, keeps
every node.
"""

import numpy as np
import pytest

from napari_aldic.engine import Reason, correlate, synthetic

SUBSET, STEP, H = 31, 8, 15
FIELD = synthetic.Affine.strain_rotation(exx=0.005, center=(128, 128), t=(1.3, -0.6))


def _speckle(field=FIELD, noise=0.5):
    r, d = synthetic.speckle_pair((256, 256), field, noise=noise)
    return r.astype(float), d.astype(float)


def _occluder():
    r, d = _speckle()
    r[:, :128] = 0
    d[:, :128] = 0
    moving = np.zeros((256, 256), bool)
    moving[:, 128:] = True
    return r, d, FIELD, moving


def _bar():
    r, d = _speckle()
    r[:, 120:136] = 0
    d[:, 120:136] = 0
    moving = np.ones((256, 256), bool)
    moving[:, 120:136] = False
    return r, d, FIELD, moving


def _periodic():
    shift = synthetic.Translation(4.2, 0.0)
    yy, xx = np.mgrid[0:256, 0:256].astype(float)
    rng = np.random.default_rng(3)

    def pattern(x, y):
        return 128 + 50 * (np.sin(2 * np.pi * x / 6) + np.sin(2 * np.pi * y / 6))

    r = pattern(xx, yy) + 0.5 * rng.standard_normal(xx.shape)
    d = pattern(xx - 4.2, yy) + 0.5 * rng.standard_normal(xx.shape)
    return r, d, shift, np.zeros((256, 256), bool)


def _check(res, field, moving):
    ut, vt = field.displacement(res.x, res.y)
    err = np.hypot(res.u - ut, res.v - vt)
    assert int(np.count_nonzero(res.valid & (err > 0.5))) == 0
    wholly = np.array([moving[int(y) - H:int(y) + H + 1, int(x) - H:int(x) + H + 1].all()
                       for x, y in zip(res.x, res.y)])
    if wholly.any():
        assert res.valid[wholly].mean() >= 0.9
    s = np.maximum(res.u_std, res.v_std)[res.valid]
    assert np.all(np.isfinite(s)) and np.all(s <= res.params.max_uncertainty)


@pytest.mark.parametrize("method", ["local", "aldic"])
@pytest.mark.parametrize("trap", [_occluder, _bar, _periodic], ids=["occluder", "bar", "periodic"])
def test_static_traps_are_never_valid(trap, method):
    r, d, field, moving = trap()
    res = correlate(r, d, subset=SUBSET, step=STEP, method=method)
    _check(res, field, moving)
    flagged = set(np.unique(res.reason[~res.valid]).tolist())
    if trap is _periodic:
        assert int(Reason.AMBIGUOUS_MATCH) in flagged
    else:
        assert int(Reason.STATIC_FEATURE) in flagged


@pytest.mark.parametrize("field", [FIELD, synthetic.Translation(0.0, 0.0)], ids=["moving", "zero"])
def test_clean_speckle_keeps_every_node(field):
    for noise in (0.5, 5.0):
        r, d = _speckle(field, noise)
        res = correlate(r, d, subset=SUBSET, step=STEP)
        assert not np.isin(res.reason, [Reason.STATIC_FEATURE, Reason.AMBIGUOUS_MATCH]).any()
        assert res.valid.mean() == 1.0


def _hbar(level=0.0):
    """A horizontal 16 px bar at grey ``level``, fixed in both images: the
    motion across its edge (v = -0.6 px) is what the edge pins."""
    r, d = _speckle()
    r[120:136] = level
    d[120:136] = level
    moving = np.ones((256, 256), bool)
    moving[120:136] = False
    return r, d, FIELD, moving


@pytest.mark.parametrize("method", ["local", "aldic"])
@pytest.mark.parametrize("level", [0.0, 5.0])
def test_horizontal_bar_is_never_valid(level, method):
    """Before the edge test 10 (bar at 0 GL) and 11 (at 5 GL) Local nodes on
    the bar's lower edge were valid and 0.5-0.58 px off: their affine warp
    bent (dv/dy = -0.05) so the bar's edge stayed put while the speckle
    beside it moved part of the way, and no pixel preferred zero motion."""
    r, d, field, moving = _hbar(level)
    res = correlate(r, d, subset=SUBSET, step=STEP, method=method)
    _check(res, field, moving)
    assert int(Reason.STATIC_FEATURE) in set(np.unique(res.reason[~res.valid]).tolist())


@pytest.mark.parametrize("trap", [_bar, _hbar], ids=["bar", "horizontal bar"])
def test_static_bars_with_quadratic_subsets(trap):
    """Second-order subsets get no zero-motion test; the edge test covers them
    (before: 4 valid nodes on the vertical bar's edge at u = 0.1 px, the truth
    1.3 px)."""
    r, d, field, moving = trap()
    res = correlate(r, d, subset=SUBSET, step=STEP, shape_function="quadratic")
    _check(res, field, moving)


def test_reason_texts():
    assert "static" in Reason.describe(Reason.STATIC_FEATURE)
    assert "ambiguous" in Reason.describe(Reason.AMBIGUOUS_MATCH)
    assert int(Reason.GLOBAL_MISMATCH) == 12  # existing codes keep their numbers


@pytest.mark.parametrize("method", ["local", "aldic"])
def test_exported_uncertainty_is_honest_at_valid_nodes(method):
    """A horizontal static bar at 5 GL noise: without the rule on the exported
    value, valid nodes carried u_std of 1.4-3 px or NaN (the validity stage's
    UNCERTAIN test judged the IC-GN model before the quality stage's u_std
    was known)."""
    r, d = _speckle(noise=5.0)
    r[120:136] = 0
    d[120:136] = 0
    res = correlate(r, d, subset=SUBSET, step=STEP, method=method)
    s = np.maximum(res.u_std, res.v_std)[res.valid]
    assert res.valid.any()
    assert np.all(np.isfinite(s)) and np.all(s <= res.params.max_uncertainty)
