"""What the first page of a report says about an analysis: where the images came
from, how the frames were tracked, and every parameter as the analysis used it
(the smoothing length and interpolation order it chose, not just "auto").

Everything is read from the results themselves (``result.meta``: inputs,
versions, timing, the AL-DIC regularisation, the interpolation chosen, the
reference frame of each increment), so a report of a run folder on disk says
the same as one of the ``SequenceResult`` in memory.
"""

from __future__ import annotations

import datetime as _dt

import numpy as np

from ..core.units import Units
from ..io.columns import software_name
from ..io.vtk import result_cells
from .layout import A4, fit_table, text_lines

__all__ = ["tracking_text", "image_sources", "parameter_rows", "analysis_page"]

#: parameters that only AL-DIC uses
_ALDIC_ONLY = ("mu", "beta", "smooth", "second_order_warp", "admm_max_iter", "admm_tol",
               "refine")
#: parameters in pixels
_PX = ("subset", "step", "search", "search_max", "init_spacing", "tol", "admm_tol",
       "max_uncertainty")


def _moving(frames):
    """The frames that were correlated (frame 0 is the reference, a zero field)."""
    return [f for f in frames if f.index != 0] or list(frames)


def _spread(values, fmt="{:g}", unit: str = "") -> str:
    """One value, or the range over the frames when they differ."""
    vals = [v for v in values if v is not None]
    if not vals:
        return "-"
    if all(v == vals[0] for v in vals):
        return fmt.format(vals[0]) + unit
    if all(isinstance(v, (int, float)) for v in vals):
        return f"{fmt.format(min(vals))} to {fmt.format(max(vals))}{unit}"
    return ", ".join(sorted({str(v) for v in vals}))


def tracking_text(frames, info: dict) -> str:
    """How the frames were correlated, from the reference frame stored in each
    result (``meta["reference_frame"]``), else from the sequence's own record."""
    moving = _moving(frames)
    if len(moving) == 1 and moving[0].index != 0:
        r = (moving[0].result.meta or {}).get("reference_frame", 0)
        return f"one pair: frame {moving[0].index} against frame {r}"
    order = sorted({f.index for f in frames} | {0})
    prev = {k: order[i - 1] for i, k in enumerate(order) if i > 0}
    refs = {f.index: (f.result.meta or {}).get("reference_frame") for f in moving}
    known = {k: int(r) for k, r in refs.items() if r is not None}
    if known and any(r != 0 for r in known.values()):
        if all(r == prev.get(k) for k, r in known.items()):
            return ("incremental: each frame against the previous one, the increments "
                    "composed back to frame 0")
        updates = sorted({r for r in known.values() if r != 0})
        return ("accumulative with reference updates at frame(s) "
                f"{', '.join(map(str, updates))}; results composed back to frame 0")
    if known or info.get("reference") == "accumulative":
        return "accumulative: every frame against frame 0"
    if info.get("reference") == "incremental":
        return ("incremental: each frame against the previous one, composed back to frame 0")
    return "every frame against frame 0"


def image_sources(frames, info: dict) -> list[str]:
    """Lines naming the reference image, the deformed images and the ROI."""
    inputs = {f.index: (f.result.meta or {}).get("inputs") or {} for f in frames}
    moving = _moving(frames)
    ref = next((d.get("reference") for d in inputs.values() if d.get("reference")), None)
    lines = [f"reference image: {ref or 'not recorded'}"]
    named = [(f.index, inputs[f.index].get("deformed")) for f in moving]
    named = [(k, n) for k, n in named if n]
    if not named:
        lines.append("deformed images: not recorded (results computed from arrays)")
    else:
        shown = named if len(named) <= 6 else named[:3] + [None] + named[-2:]
        parts = ["..." if s is None else f"frame {s[0]}: {s[1]}" for s in shown]
        lines.append(f"deformed images ({len(named)}): " + "; ".join(parts))
    roi_file = next((d.get("roi") for d in inputs.values() if d.get("roi")), None)
    roi = frames[-1].result.roi
    if roi_file:
        lines.append(f"region of interest: {roi_file}")
    elif roi is not None:
        lines.append(f"region of interest: mask stored with the result "
                     f"({100.0 * np.mean(roi):.1f} % of the image)")
    else:
        lines.append("region of interest: the whole image")
    if info.get("folder"):
        lines.append(f"results read from the run folder: {info['folder']}")
    if info.get("source") and info.get("source") != info.get("folder"):
        lines.append(f"image stack: {info['source']}")
    return lines


def _reg(res) -> dict:
    return (res.meta or {}).get("regularisation") or {}


def parameter_rows(frames) -> list[list[str]]:
    """``[parameter, value used, note]`` for every analysis parameter, with what
    the analysis chose where the request was automatic."""
    moving = _moving(frames)
    p = moving[-1].result.params
    aldic = p.method == "aldic"
    used = {
        "interpolation": (_spread([(f.result.meta or {}).get("interpolation")
                                   for f in moving], "{}"), f"requested {p.interpolation}"),
        "search_max": ("automatic" if p.search_max is None else f"{p.search_max}",
                       "widens by itself up to this" if p.search_max is None else ""),
        "init_spacing": ("automatic" if p.init_spacing is None else f"{p.init_spacing}",
                         "about 2 x subset" if p.init_spacing is None else ""),
    }
    if aldic:
        regs = [_reg(f.result) for f in moving]
        how = {"auto": "chosen from the image noise", "fixed": "fixed"}
        modes = {r.get("mode") for r in regs if r}
        used["smooth"] = (_spread([r.get("smooth_px") for r in regs], "{:.2f}", " px"),
                          f"requested {p.smooth}; "
                          + (", ".join(how.get(m, str(m)) for m in modes if m) or "-"))
        used["second_order_warp"] = (_spread([r.get("second_order_warp") for r in regs], "{}"),
                                     f"requested {p.second_order_warp}")
        iters = [len((f.result.meta or {}).get("admm_history") or []) for f in moving]
        used["admm_max_iter"] = (f"{p.admm_max_iter}", "ADMM iterations used: "
                                 + _spread(iters, "{:d}"))
    rows = []
    for name, value in p.to_dict().items():
        if name in used:
            shown, note = used[name]
        else:
            shown = "none" if value is None or value == [] or value == () else str(value)
            note = "px" if name in _PX else ""
        if not aldic and name in _ALDIC_ONLY:
            note = "not used by Local DIC"
        rows.append([name, shown, note])
    totals = [(f.result.meta or {}).get("timing", {}).get("total") for f in moving]
    totals = [t for t in totals if t is not None]
    if totals:
        rows.append(["time per frame", _spread([round(t, 3) for t in totals], "{:g}", " s"),
                     f"{sum(totals):.2f} s for {len(totals)} frame(s)"])
    return rows


def _versions(frames) -> str:
    versions = (_moving(frames)[-1].result.meta or {}).get("versions") or {}
    return ", ".join(f"{k} {v}" for k, v in versions.items()) or "not recorded"


def analysis_page(frames, units: Units, info: dict, line):
    """Page 1 of the report: provenance and the parameter table."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=A4)
    first = frames[-1].result
    idx = info.get("frames_all") or [f.index for f in frames]
    s = info.get("strain")
    strain = ("not computed" if not s else
              f"{s['measure'].replace('_', '-')} by {s['method'].replace('_', ' ')}, window "
              f"{s['window']} nodes, virtual strain gauge {s['vsg_px']:g} px "
              f"({s['vsg_px'] * units.pixel_size:g} {units.unit})")
    n_cells = len(result_cells(first))
    lines = [("napari-aldic DIC report", {"size": 17, "weight": "bold", "space": 0.6}),
             (f"written {_dt.datetime.now().isoformat(timespec='seconds')} by "
              f"{software_name()}; analysed with {_versions(frames)}", {}),
             *[(t, {}) for t in image_sources(frames, info)],
             (f"frames: {len(idx)} ({idx[0]} to {idx[-1]}); tracking: "
              f"{tracking_text(frames, info)}", {}),
             (f"image {first.image_shape[1]} x {first.image_shape[0]} px; {len(first)} nodes, "
              f"{n_cells} Q4 cells; method {_method_name(first)}", {}),
             (f"units: {units.describe()}", {}),
             (f"strain: {strain}", {}),
             ("profile line: " + ("none" if line is None else
                                  f"({line[0]:g}, {line[1]:g}) to ({line[2]:g}, {line[3]:g}) px"),
              {"space": 1.0}),
             ("Analysis parameters as used (lengths in pixels)",
              {"size": 11.5, "weight": "bold", "space": 0.3})]
    y = text_lines(fig, lines)
    ax = fig.add_axes((0.07, 0.03, 0.86, y - 0.04))
    fit_table(ax, ["parameter", "value used", "note"], parameter_rows(frames),
              [0.24, 0.30, 0.46], fontsize=8, align=["left", "left", "left"])
    return fig


def _method_name(res) -> str:
    return "AL-DIC (augmented Lagrangian)" if res.params.method == "aldic" else \
        "Local DIC (subset IC-GN)"
