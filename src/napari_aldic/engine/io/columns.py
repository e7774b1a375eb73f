"""Per-frame columns shared by every export: field names, units, metadata lines."""

from __future__ import annotations

import numpy as np

from ..core.reasons import Reason
from ..core.results import DICResult
from ..core.units import Units
from .runs import RATE_NAMES, STRAIN_NAMES, Frame

# =================================================================== columns
#: the fields that figures, images and reports can show:
#: field name -> (title, kind); the kind (length, velocity, rate, strain, angle,
#: none) picks the unit (:func:`unit_of`). Not the plugin's layer table.
FIELD_INFO: dict[str, tuple[str, str]] = {
    "u": ("u (x displacement)", "length"),
    "v": ("v (y displacement)", "length"),
    "magnitude": ("|u| (displacement magnitude)", "length"),
    "vx": ("x velocity", "velocity"),
    "vy": ("y velocity", "velocity"),
    "exx": ("strain exx", "strain"),
    "eyy": ("strain eyy", "strain"),
    "exy": ("strain exy (tensor shear)", "strain"),
    "e1": ("major principal strain e1", "strain"),
    "e2": ("minor principal strain e2", "strain"),
    "max_shear": ("maximum shear strain", "strain"),
    "von_mises": ("equivalent (von Mises) strain", "strain"),
    "rotation": ("rotation", "angle"),
    "exx_rate": ("strain rate d(exx)/dt", "rate"),
    "eyy_rate": ("strain rate d(eyy)/dt", "rate"),
    "exy_rate": ("strain rate d(exy)/dt", "rate"),
    "zncc": ("ZNCC (correlation quality)", "none"),
    "u_std": ("standard uncertainty of u", "length"),
    "v_std": ("standard uncertainty of v", "length"),
    "sssig": ("SSSIG (speckle quality, GL²)", "none"),
    "mig": ("mean intensity gradient (GL/px)", "none"),
}

#: per-node measurement-quality fields of a result (``None`` when not computed)
QUALITY_FIELDS = ("u_std", "v_std", "sssig", "mig")


def unit_of(kind: str, units: Units) -> str:
    """The unit of a quantity of ``kind`` (see :data:`FIELD_INFO`) in ``units``."""
    return {"length": units.unit, "velocity": units.velocity_unit, "rate": units.rate_unit,
            "angle": "rad", "px": "px", "time": units.time_unit}.get(kind, "")


def same_nodes(a: DICResult, b: DICResult) -> bool:
    """True when two results have the same nodes (same coordinates, same order)."""
    return a.x.shape == b.x.shape and np.array_equal(a.x, b.x) and np.array_equal(a.y, b.y)


def frame_columns(fr: Frame, units: Units) -> dict[str, tuple[np.ndarray, str]]:
    """Per-node columns of one frame: ``name -> (values, unit)``.

    Lengths are in ``units.unit`` (``x_px``/``y_px`` stay in pixels);
    velocities and strain rates appear only with a frame interval; they are
    backward differences to the previous frame (frame 0 = zero field), NaN
    at frame 0 and where the previous frame has other nodes.

    The one rule of every export (:data:`UNTRUSTED_RULE`): measured fields
    (``u``, ``v``, ``magnitude``, velocities, strains, rates) are NaN where
    the node (or its strain) is not trusted, for accumulative and incremental
    results alike; ``u_attempt``/``v_attempt`` keep the solver's value at
    every node, untrusted ones included (NaN where it has none), for diagnosis.
    """
    res, ps = fr.result, units.pixel_size
    n = len(res)
    L = units.unit
    u, v = trusted_displacement(res)
    cols: dict[str, tuple[np.ndarray, str]] = {
        "node": (np.arange(n), ""),
        "x_px": (np.asarray(res.x, float), "px"),
        "y_px": (np.asarray(res.y, float), "px"),
        "x": (res.x * ps, L),
        "y": (res.y * ps, L),
        "u": (u * ps, L),
        "v": (v * ps, L),
        "magnitude": (np.hypot(u, v) * ps, L),
    }
    dt_frames = None
    prev_u = prev_v = None
    prev_strain = None
    if units.has_time:
        p = fr.prev
        if fr.index > 0 and (p is None or same_nodes(p.result, res)):
            dt_frames = fr.index - (0 if p is None else p.index)
            if p is None:
                prev_u = prev_v = np.zeros(n)
            else:
                prev_u, prev_v = trusted_displacement(p.result)
                prev_strain = p.strain
        dt = None if dt_frames is None else dt_frames * units.frame_interval
        if dt is None:
            vx = vy = np.full(n, np.nan)
        else:
            vx, vy = (u - prev_u) * ps / dt, (v - prev_v) * ps / dt
        cols["vx"] = (vx, units.velocity_unit)
        cols["vy"] = (vy, units.velocity_unit)
    s = fr.strain
    if s is not None:
        for name in STRAIN_NAMES:
            cols[name] = (trusted_strain(s, name), "rad" if name == "rotation" else "")
        if units.has_time:
            for name in RATE_NAMES:
                if dt_frames is None:
                    rate = np.full(n, np.nan)
                else:
                    if fr.prev is None:
                        before = np.zeros(n)
                    elif prev_strain is not None:
                        before = trusted_strain(prev_strain, name)
                    else:
                        before = np.full(n, np.nan)
                    rate = (trusted_strain(s, name) - before) / (dt_frames
                                                                  * units.frame_interval)
                cols[f"{name}_rate"] = (rate, units.rate_unit)
        cols["strain_valid"] = (np.asarray(s.valid, bool), "")
    cols["valid"] = (np.asarray(res.valid, bool), "")
    cols["reason"] = (np.asarray(res.reason, np.int64), "")
    cols["zncc"] = (np.asarray(res.zncc, float), "")
    for name in QUALITY_FIELDS:  # kept at every node, like zncc; NaN when not computed
        vals = getattr(res, name, None)
        vals = np.full(n, np.nan) if vals is None else np.asarray(vals, float)
        length = name.endswith("_std")
        # grey levels (GL) of the reference image: squared gradients summed, mean gradient
        unit = L if length else {"sssig": "GL^2", "mig": "GL/px"}[name]
        cols[name] = (vals * (ps if length else 1.0), unit)
    cols["u_attempt"] = (np.asarray(res.u, float) * ps, L)
    cols["v_attempt"] = (np.asarray(res.v, float) * ps, L)
    return cols


#: the rule for untrusted nodes that every export states (CSV header, VTU comment, MAT)
UNTRUSTED_RULE = ("u, v, magnitude, velocities, strains and rates are NaN where the node "
                  "(or its strain) is not trusted (valid = 0); u_attempt and v_attempt hold "
                  "the solver's value at every node, untrusted ones included (NaN where it "
                  "has none), for diagnosis only")


def trusted_displacement(res: DICResult) -> tuple[np.ndarray, np.ndarray]:
    """``(u, v)`` in pixels, NaN at the nodes that are not trusted."""
    ok = np.asarray(res.valid, bool)
    return (np.where(ok, np.asarray(res.u, float), np.nan),
            np.where(ok, np.asarray(res.v, float), np.nan))


def trusted_strain(strain, name: str) -> np.ndarray:
    """Strain component ``name`` of a ``StrainResult``, NaN where it is not trusted."""
    return np.where(np.asarray(strain.valid, bool), np.asarray(getattr(strain, name), float),
                    np.nan)


def reason_lines() -> list[str]:
    return [f"{int(r)}={Reason.describe(int(r))}" for r in Reason]


def software_name() -> str:
    from ..core.version import __version__

    return f"napari-aldic {__version__}"


