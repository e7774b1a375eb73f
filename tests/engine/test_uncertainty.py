"""Per-node standard uncertainty of u, v: stored with the result and close to the real error."""

from __future__ import annotations

import numpy as np

from napari_aldic.engine import correlate, load_result, synthetic as S


def test_predicted_uncertainty_matches_the_actual_error_and_survives_a_save(tmp_path):
    f = S.Translation(2.3, -1.4)
    errs, preds = [], []
    for seed in (1, 2, 3):
        ref, dfm = S.speckle_pair((192, 192), f, noise=12.0, seed=seed)
        res = correlate(ref, dfm, subset=21, step=10, method="local", max_uncertainty=None)
        ok = res.valid
        assert res.u_std is not None and np.isfinite(res.u_std[ok]).all()
        errs.append(np.concatenate([res.u[ok] - 2.3, res.v[ok] + 1.4]))
        preds.append(np.concatenate([res.u_std[ok], res.v_std[ok]]))
    rms = lambda a: np.sqrt(np.mean(np.concatenate(a) ** 2))  # noqa: E731
    ratio = rms(errs) / rms(preds)
    # a wrong model (e.g. noise of one image only, or no noise at all) is off by >= 1.4x;
    # the previous model (uncorrected residual, 2 x 2 matrix) was 1.2-1.3x low here, the
    # model of dic.quality is within the 20 % of issue 12 (measured 0.96)
    assert 0.8 < ratio < 1.2, ratio
    back = load_result(res.save(tmp_path / "r.npz"))
    np.testing.assert_array_equal(back.u_std, res.u_std)
    np.testing.assert_array_equal(back.v_std, res.v_std)
