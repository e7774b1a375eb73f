"""The ADMM local step starts from the linear prediction of its optimum
(``icgn_translation``'s ``prior``): one sampled IC-GN step on nearly every
node instead of two, and the same result within IC-GN's tolerance. The
prediction follows the gradient *and* the curvature of the second-order warp,
and a settled node whose samples barely move takes it without sampling."""

import numpy as np
import pytest

import napari_aldic.engine.dic.admm as AD
from napari_aldic.engine import correlate, synthetic
from napari_aldic.engine.dic.icgn import (
    PREDICTION_MISFIT,
    PREDICTION_REACH,
    icgn_solve_translation,
)
from napari_aldic.engine.dic.reliability import GLOBAL_TOLERANCE
from napari_aldic.engine.kernels.translation import (
    predicted_start,
    prediction_holds,
    prediction_moments,
)

AFFINE = synthetic.Affine.strain_rotation(exx=0.003, angle_deg=0.3, center=(128, 128),
                                          t=(0.7, -0.4))
#: a curved field: the auto regularisation bends the subsets (second-order warp)
WAVE = synthetic.Sinusoid(amplitude_u=0.5, amplitude_v=0.35, wavelength=128.0)


#: the settled flags of each local pass of the last ``_run``, at its active nodes
SETTLED: list = []


def _run(monkeypatch, mode: str, field=AFFINE, **kw):
    """AL-DIC with the local step's prior dropped (``plain``), with every node
    sampled (``sampled``), with no start settled (``unsettled``) or as it runs
    (``taken``); the iterations of each local pass at its active nodes (and
    in ``SETTLED`` the settled flags there)."""
    ref, dfm = synthetic.speckle_pair((256, 256), field, noise=2.0, seed=3)
    iterations = []
    SETTLED.clear()

    def spy(*args, **kwargs):
        assert kwargs["prior"].shape[1] == 12 and kwargs["settled"] is not None
        if mode == "plain":
            kwargs = dict(kwargs, prior=None, settled=None)
        elif mode == "sampled":
            kwargs = dict(kwargs, settled=None)
        elif mode == "unsettled":  # no start is a sampled optimum
            kwargs = dict(kwargs, settled=np.zeros_like(kwargs["settled"]))
        out = icgn_solve_translation(*args, **kwargs)
        iterations.append(out[2][args[10]])  # args[10]: the active nodes
        SETTLED.append(None if kwargs["settled"] is None else kwargs["settled"][args[10]])
        return out
    monkeypatch.setattr(AD, "icgn_solve_translation", spy)
    res = correlate(ref, dfm, subset=21, step=6, method="aldic", **kw)
    return res, iterations


def _rms_error(res, field):
    ut, vt = field.displacement(res.x, res.y)
    return float(np.sqrt(np.mean((np.hypot(res.u - ut, res.v - vt)[res.valid]) ** 2)))


def test_predicted_start_saves_a_step_and_keeps_the_result(monkeypatch):
    res, its = _run(monkeypatch, "sampled")
    plain, its_plain = _run(monkeypatch, "plain")
    # Local's gradient noise moves each node's optimum by more than tol: from
    # the Local start nearly every node needs a second step, from the
    # prediction (penalty pull and gradient change) nearly none does
    assert its_plain[0].mean() > 1.5
    assert its[0].mean() < 1.15
    np.testing.assert_array_equal(res.valid, plain.valid)
    ok = res.valid
    assert ok.sum() > 0.9 * ok.size
    # the same fixed point within IC-GN's tolerance (1e-3 px), far below the noise
    assert np.abs(res.u - plain.u)[ok].max() < 1e-4
    assert np.abs(res.v - plain.v)[ok].max() < 1e-4
    assert np.abs(res.u_std - plain.u_std)[ok].max() < 1e-5
    assert _rms_error(res, AFFINE) <= 1.001 * _rms_error(plain, AFFINE)


def test_the_prediction_follows_the_second_order_warp(monkeypatch):
    """Bending the subsets by the global field's curvature moves the samples
    as a gradient change does: left out of the prediction, this field needed
    a second sampled step at 99.6 % of the nodes of the first pass (2.05
    steps a node) and 1.27 steps a node in the second; now 17.5 % and 1.00."""
    res, its = _run(monkeypatch, "sampled", WAVE)
    assert res.meta["regularisation"]["second_order_warp"]
    assert res.valid.mean() > 0.9
    assert its[0].mean() < 1.3, [i.mean() for i in its]
    assert (its[0] > 1).mean() < 0.3
    assert its[1].mean() < 1.05


@pytest.mark.parametrize("field", [AFFINE, WAVE], ids=["affine", "curved"])
def test_settled_nodes_take_the_prediction_without_sampling(monkeypatch, field):
    res, its = _run(monkeypatch, "taken", field)
    settled = list(SETTLED)
    _, its_unsettled = _run(monkeypatch, "unsettled", field)
    assert all((i > 0).all() for i in its_unsettled)
    sampled, _ = _run(monkeypatch, "sampled", field)
    # nearly every trusted Local result is a settled optimum whose samples
    # move by hundredths of a pixel on the affine field: no sampled step; the
    # curved field's first pass bends the subsets by more, its later ones not
    # only settled nodes (sampled optima) take it: none when no start is one
    assert all(s[i == 0].all() for i, s in zip(its, settled))
    taken = [(i == 0).mean() for i in its]
    assert taken[0] > 0.8 if field is AFFINE else max(taken[1:]) > 0.8, taken
    assert [h["local_predicted"] for h in res.meta["admm_history"]] == [
        int((i == 0).sum()) for i in its]
    np.testing.assert_array_equal(res.valid, sampled.valid)
    ok = res.valid
    # the prediction's error is second order in that move: within IC-GN's
    # tolerance (1e-3 px) everywhere, a few 1e-4 px RMS (measured: 3.5e-4 and
    # 9.3e-4 px at most, 0.6e-4 and 1.9e-4 px RMS)
    moved = np.hypot(res.u - sampled.u, res.v - sampled.v)[ok]
    assert moved.max() < 1e-3
    assert np.sqrt(np.mean(moved**2)) < 2.5e-4
    # the run's convergence record and summary count them: 0 iterations
    assert res.meta["convergence"]["predicted"] == int((res.iterations[ok] == 0).sum()) > 0
    assert f"{int((its[-1] == 0).sum())} nodes took their linear prediction" in res.summary()
    assert np.isfinite(res.zncc[ok]).all()  # not sampled again: the last ZNCC measured
    assert np.abs(res.zncc - sampled.zncc)[ok].max() < 1e-3
    assert _rms_error(res, field) <= 1.01 * _rms_error(sampled, field)


def test_when_a_prediction_holds():
    # an isotropic subset (H = 2 I) of a node in the middle of a 200 px image
    grad, curv = np.zeros((1, 4)), np.zeros((1, 6))

    def holds(moved, h=(2.0, 0.0, 0.0, 2.0), x0=100, curv=curv, quad=False):
        return prediction_holds(moved, *h, PREDICTION_REACH, PREDICTION_MISFIT, x0, 100,
                                0.3, -0.2, grad, curv, 0, quad, 10, 199.0, 199.0)
    assert PREDICTION_MISFIT <= GLOBAL_TOLERANCE / 2  # never hides a global mismatch
    assert holds(0.04)
    assert not holds(0.06)  # beyond reach: sampled
    assert not holds(np.nan)
    # an elongated texture (λ_min = tr/50) loses ZNCC along its weak direction
    assert not holds(0.04, h=(1.96, 0.0, 0.0, 0.04))
    assert holds(0.01, h=(1.96, 0.0, 0.0, 0.04))
    assert not holds(0.04, h=(1.0, 0.0, 0.0, 0.0))  # no texture along y
    # the warped subset must stay inside the image, bent by its curvature too
    # (half-width 10, u = 0.3: x0 - 9.7 >= 0 and x0 + 10.3 <= 199)
    assert not holds(0.01, x0=9) and holds(0.01, x0=10)
    assert holds(0.01, x0=188) and not holds(0.01, x0=189)
    bent = np.array([[0.02, 0.0, 0.0, 0.0, 0.0, 0.0]])  # 0.5 * 0.02 * 10² = 1 px
    assert not holds(0.01, x0=10, curv=bent, quad=True)
    assert holds(0.01, x0=11, curv=bent, quad=True)


def test_prediction_moments_are_the_subsets_sums_and_the_shift_a_bound():
    rng = np.random.default_rng(0)
    fgx, fgy, egx, egy = (rng.normal(size=(64, 64)).astype(np.float32) for _ in range(4))
    h, side = 7, 15
    masks = (rng.random((1, side, side)) > 0.3).astype(np.uint8)  # a cut subset's component
    slot, nx, ny = np.array([-1, 0], np.int32), np.array([20, 40]), np.array([30, 25])
    rows, cols = np.mgrid[-h:h + 1, -h:h + 1]
    for k in (0, 1):
        mom = np.empty((4, 6))
        prediction_moments(fgx, fgy, egx, egy, masks, slot, nx, ny, k, h, mom)
        keep = np.ones((side, side), bool) if slot[k] < 0 else masks[0] == 1

        def window(im, k=k, keep=keep):
            return im[ny[k] - h:ny[k] + h + 1, nx[k] - h:nx[k] + h + 1].astype(float)[keep]
        gx, gy, ex, ey = map(window, (fgx, fgy, egx, egy))
        dx, dy = cols[keep].astype(float), rows[keep].astype(float)
        weights = (np.ones_like(dx), dx, dy, dx * dx, dx * dy, dy * dy)
        expect = [[np.sum(p * w) for w in weights] for p in (gx * ex, gx * ey, gy * ex, gy * ey)]
        np.testing.assert_allclose(mom, expect, rtol=1e-9, atol=1e-9)
    # the shift bound: at least the largest sample move of the whole square
    prior = np.zeros((1, 12))
    prior[0, 2:] = rng.normal(scale=1e-3, size=10)
    grad, curv = rng.normal(scale=1e-3, size=(1, 4)), rng.normal(scale=1e-4, size=(1, 6))
    system = (1.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0)
    *_, shift = predicted_start(0.0, 0.0, prior, 0, 0.0, 0.0, system, mom, grad, curv, True, h)
    d = grad[0] - prior[0, 2:6]
    c = curv[0] - prior[0, 6:]
    def bend(c0, c1, c2):
        return 0.5 * c0 * cols**2 + c1 * cols * rows + 0.5 * c2 * rows**2
    ax = d[0] * cols + d[1] * rows + bend(*c[:3])
    ay = d[2] * cols + d[3] * rows + bend(*c[3:])
    largest = np.hypot(ax, ay).max()
    assert largest <= shift < 2.5 * largest
