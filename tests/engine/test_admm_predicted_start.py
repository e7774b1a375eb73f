"""The ADMM local step starts from the linear prediction of its optimum
(``icgn_translation``'s ``prior``): one sampled IC-GN step on nearly every
node instead of two, and the same result within IC-GN's tolerance."""

import numpy as np

import napari_aldic.engine.dic.admm as AD
from napari_aldic.engine import correlate, synthetic
from napari_aldic.engine.dic.icgn import icgn_solve_translation


def _run(monkeypatch, predicted: bool):
    f = synthetic.Affine.strain_rotation(exx=0.003, angle_deg=0.3, center=(128, 128),
                                         t=(0.7, -0.4))
    ref, dfm = synthetic.speckle_pair((256, 256), f, noise=2.0, seed=3)
    iterations = []

    def spy(*args, **kwargs):
        assert kwargs["prior"] is not None and kwargs["prior"].shape[1] == 6
        if not predicted:
            kwargs = dict(kwargs, prior=None)
        out = icgn_solve_translation(*args, **kwargs)
        iterations.append(out[2][args[10]].mean())  # args[10]: the active nodes
        return out
    monkeypatch.setattr(AD, "icgn_solve_translation", spy)
    res = correlate(ref, dfm, subset=21, step=6, method="aldic")
    return res, iterations, f


def test_predicted_start_saves_a_step_and_keeps_the_result(monkeypatch):
    res, its, field = _run(monkeypatch, True)
    plain, its_plain, _ = _run(monkeypatch, False)
    # Local's gradient noise moves each node's optimum by more than tol: from
    # the Local start nearly every node needs a second step, from the
    # prediction (penalty pull and gradient change) nearly none does
    assert its_plain[0] > 1.5
    assert its[0] < 1.15
    np.testing.assert_array_equal(res.valid, plain.valid)
    ok = res.valid
    assert ok.sum() > 0.9 * ok.size
    # the same fixed point within IC-GN's tolerance (1e-3 px), far below the noise
    assert np.abs(res.u - plain.u)[ok].max() < 1e-4
    assert np.abs(res.v - plain.v)[ok].max() < 1e-4
    assert np.abs(res.u_std - plain.u_std)[ok].max() < 1e-5
    ut, vt = field.displacement(res.x, res.y)
    err = np.hypot(res.u - ut, res.v - vt)[ok]
    err_plain = np.hypot(plain.u - ut, plain.v - vt)[ok]
    assert np.sqrt(np.mean(err**2)) <= 1.001 * np.sqrt(np.mean(err_plain**2))
