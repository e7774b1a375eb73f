"""Noise floor from a static pair: two images of the unloaded specimen.

The true displacement between them is a rigid motion at most (the specimen
or camera may drift a little), and the true strain is zero, so the scatter
of the measured fields about a fitted rigid motion is the measurement's
noise floor for these settings, as the iDICs Good Practices Guide (2018,
section on noise-floor measurement) asks to report with every result.
"""

from __future__ import annotations

import numpy as np

from ..core.params import StrainParams
from .correlate import correlate
from .strain import compute_strain

__all__ = ["noise_floor", "NOISE_FLOOR_KEYS"]

#: the quantities of a noise floor (standard deviations over valid nodes)
NOISE_FLOOR_KEYS = ("u", "v", "exx", "eyy", "exy")


def _rigid_residual(x, y, u, v):
    """``u``, ``v`` minus their least-squares rigid motion (translation and
    small rotation): a drift of the specimen is no noise."""
    a = np.column_stack([np.ones_like(x), x - x.mean(), y - y.mean()])
    # u = tx - w (y - ym), v = ty + w (x - xm): one shared rotation w
    n = x.size
    mat = np.zeros((2 * n, 3))
    mat[:n, 0] = 1.0
    mat[:n, 2] = -a[:, 2]
    mat[n:, 1] = 1.0
    mat[n:, 2] = a[:, 1]
    coef, *_ = np.linalg.lstsq(mat, np.concatenate([u, v]), rcond=None)
    r = np.concatenate([u, v]) - mat @ coef
    return r[:n], r[n:]


def noise_floor(reference, static, roi=None, *, strain_window: int = StrainParams.window,
                strain_method: str = StrainParams.method, **kwargs) -> dict:
    """Displacement and strain noise of a static pair with the given settings.

    Parameters
    ----------
    reference, static : (H, W) array
        Two images of the unloaded, unmoved specimen.
    roi : (H, W) bool, optional
    strain_window, strain_method
        As :func:`~napari_aldic.engine.compute_strain`.
    **kwargs
        Passed to :func:`~napari_aldic.engine.correlate` (``subset``,
        ``step``, ``method``, ...): use the settings of the measurement.

    Returns
    -------
    dict
        ``u_std_px``, ``v_std_px`` (scatter about the fitted rigid motion),
        ``exx_std``, ``eyy_std``, ``exy_std`` (about their means), the rigid
        motion ``drift_px`` (mean u, v), ``n_valid`` and the settings
        (``subset``, ``step``, ``method``, ``strain_window``); the values are
        NaN when fewer than 3 nodes are valid.
    """
    res = correlate(reference, static, roi, **kwargs)
    ok = res.valid
    out = {"subset": res.params.subset, "step": res.params.step, "method": res.params.method,
           "strain_window": int(strain_window), "n_valid": int(ok.sum())}
    if ok.sum() < 3:
        out.update({f"{k}_std" + ("_px" if k in "uv" else ""): float("nan")
                    for k in NOISE_FLOOR_KEYS})
        out["drift_px"] = [float("nan"), float("nan")]
        return out
    du, dv = _rigid_residual(res.x[ok], res.y[ok], res.u[ok], res.v[ok])
    out["u_std_px"] = float(np.std(du, ddof=1))
    out["v_std_px"] = float(np.std(dv, ddof=1))
    out["drift_px"] = [float(res.u[ok].mean()), float(res.v[ok].mean())]
    st = compute_strain(res, window=strain_window, method=strain_method,
                        measure="infinitesimal")
    sv = np.asarray(st.valid, bool)
    for k in ("exx", "eyy", "exy"):
        vals = np.asarray(getattr(st, k), float)[sv]
        vals = vals[np.isfinite(vals)]
        out[f"{k}_std"] = float(np.std(vals, ddof=1)) if vals.size > 2 else float("nan")
    return out
