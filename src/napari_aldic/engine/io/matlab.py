"""MATLAB .mat export and reader."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..core.files import atomic_write, target_path
from ..core.reasons import Reason
from ..core.units import Units
from .columns import QUALITY_FIELDS, UNTRUSTED_RULE, frame_columns, same_nodes, software_name
from .runs import (
    MAT_FORMAT,
    MAT_FORMAT_VERSION,
    RATE_NAMES,
    STRAIN_NAMES,
    Frame,
    collect_frames,
)


# =================================================================== MATLAB
def _mat_frame(fr: Frame, units: Units) -> dict[str, Any]:
    res = fr.result
    cols = frame_columns(fr, units)
    d: dict[str, Any] = {
        "frame": int(fr.index),
        "time": float(units.time(fr.index)) if units.has_time else np.nan,
        "x_px": np.asarray(res.x, float), "y_px": np.asarray(res.y, float),
        "u_px": np.asarray(res.u, float), "v_px": np.asarray(res.v, float),
    }
    for k in ("x", "y", "u", "v", "magnitude", "u_attempt", "v_attempt"):
        d[k] = cols[k][0]
    for k in ("vx", "vy"):
        d[k] = cols[k][0] if k in cols else np.empty((0, 1))
    for k in ("dudx", "dudy", "dvdx", "dvdy", "zncc"):
        d[k] = np.asarray(getattr(res, k), float)
    for k in QUALITY_FIELDS:  # empty when the result has none
        d[k] = cols[k][0] if k in cols else np.empty((0, 1))
    d["valid"] = np.asarray(res.valid, np.uint8)
    d["reason"] = np.asarray(res.reason, np.int8)
    d["iterations"] = np.asarray(res.iterations, np.int32)
    d["grid_ix"] = np.asarray(res.grid_ix, np.int64)
    d["grid_iy"] = np.asarray(res.grid_iy, np.int64)
    d["grid_xs"] = np.asarray(res.grid_xs, np.int64)
    d["grid_ys"] = np.asarray(res.grid_ys, np.int64)
    for k in STRAIN_NAMES + tuple(f"{n}_rate" for n in RATE_NAMES) + ("strain_valid",):
        if k in cols:
            v = cols[k][0]
            d[k] = v.astype(np.uint8) if v.dtype == bool else v
        else:
            d[k] = np.empty((0, 1))
    for k in ("u_local", "v_local"):
        v = getattr(res, k)
        d[k] = np.empty((0, 1)) if v is None else np.asarray(v, float)
    el = res.elements
    d["elements"] = np.empty((0, 4), np.int64) if el is None else np.asarray(el, np.int64)
    d["faces"] = d["elements"] + 1  # 1-based, for MATLAB's patch()
    hg = res.hanging
    d["hanging"] = np.empty((0, 3), np.int64) if hg is None else np.asarray(hg, np.int64)
    d["meta_json"] = json.dumps(res.meta, default=str)
    return d


def export_mat(data, path, *, units=None, strain=True, frames=None) -> Path:
    """Write a MATLAB ``.mat`` file (v5, compressed) readable by ``load`` and
    ``scipy.io.loadmat``.

    Top-level variables: ``format``, ``format_version``, ``software``,
    ``pixel_size``, ``unit``, ``frame_interval`` (NaN if unknown),
    ``time_unit``, ``frame`` (1 x F), ``time`` (1 x F), ``image_shape``,
    ``params_json`` and ``params`` (struct), ``strain_settings`` (struct),
    ``reason_codes`` (cell), ``untrusted_rule`` (text: ``u``, ``v``,
    ``magnitude``, velocities and strains are NaN at untrusted nodes,
    ``u_attempt``/``v_attempt`` and ``u_px``/``v_px`` keep the solver's value),
    ``roi`` (uint8, rows x cols, when stored), and
    ``frames``: a 1 x F struct array, one element per frame, with the fields
    listed in ``docs/exports.md``. When every frame has the same nodes, the
    per-node fields are also stacked as F x N matrices at top level
    (``u``, ``v``, ``exx``, ... with ``x``, ``y`` as N x 1). Indices
    (``grid_ix``, ``elements``, ``hanging``) are 0-based; ``faces`` is
    ``elements + 1`` for MATLAB. Read it back with :func:`load_mat`.
    """
    import scipy.io as sio

    path = target_path(path, (".mat",))
    fr_list, units, info = collect_frames(data, frames=frames, strain=strain, units=units)
    per = [_mat_frame(fr, units) for fr in fr_list]
    names = list(per[0])
    st = np.empty((1, len(per)), dtype=[(k, object) for k in names])
    for j, d in enumerate(per):
        st[0, j] = tuple(d[k] for k in names)
    params = info["params"]
    out: dict[str, Any] = {
        "format": MAT_FORMAT,
        "format_version": MAT_FORMAT_VERSION,
        "software": software_name(),
        "pixel_size": units.pixel_size,
        "unit": units.unit,
        "frame_interval": np.nan if units.frame_interval is None else units.frame_interval,
        "time_unit": units.time_unit,
        "frame": np.array([[fr.index for fr in fr_list]], float),
        "time": np.array([[units.time(fr.index) if units.has_time else np.nan
                           for fr in fr_list]], float),
        "image_shape": np.array([list(info["image_shape"])], float),
        "params_json": json.dumps(params.to_dict()),
        "params": {k: (np.nan if v is None else (np.array(v, float) if k == "seeds" else v))
                   for k, v in params.to_dict().items()},
        "strain_settings": info["strain"] or {},
        "reason_codes": np.array([f"{int(r)}: {Reason.describe(int(r))}" for r in Reason],
                                 dtype=object),
        "source": info.get("source") or "",
        "untrusted_rule": UNTRUSTED_RULE + "; u_px, v_px and the gradients are the result "
                          "as stored (best attempt at untrusted nodes), for load_mat",
        "frames": st,
    }
    roi = fr_list[0].result.roi
    if roi is not None:
        out["roi"] = np.asarray(roi, np.uint8)
    if all(same_nodes(fr.result, fr_list[0].result) for fr in fr_list):
        out["x"] = per[0]["x"]
        out["y"] = per[0]["y"]
        out["x_px"] = per[0]["x_px"]
        out["y_px"] = per[0]["y_px"]
        for k in names:
            v = per[0][k]
            if k in ("x", "y", "x_px", "y_px") or not isinstance(v, np.ndarray) or \
                    v.ndim != 1 or v.shape[0] != len(fr_list[0].result) or k in ("grid_ix",
                                                                                 "grid_iy"):
                continue
            out[k] = np.stack([d[k] for d in per])
    with atomic_write(path) as tmp, open(tmp, "wb") as fh:
        sio.savemat(fh, out, do_compression=True, oned_as="column")
    return path
