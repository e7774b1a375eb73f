"""Multipage PDF report of a DIC analysis (matplotlib ``PdfPages``, headless).

Pages, in order (see ``docs/exports.md``):

1. **Analysis**: software, source, frames, units, strain settings and the
   table of every analysis parameter.
2. **Mesh and nodes**: the nodes over the ROI, coloured by their validity
   reason, with the Q4 mesh (and the profile line, when given).
3. **One page per chosen frame**: maps of u, v and |u| (physical units) and
   of exx, eyy, exy (or the ZNCC without strain), shared colour limits.
4. **Line profiles** (only with ``line=(x0, y0, x1, y1)``): u, v and the
   strains sampled along the line for every chosen frame.
5. **Summary statistics**: mean (and standard deviation) over the trusted
   nodes of the ROI of u, v and the strains against frame or time.
6. **Validity**: node counts per reason for every frame.

So a report has ``4 + len(frames)`` pages, plus one with a line.
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import numpy as np

from ..core.files import atomic_write, target_path
from ..core.reasons import Reason
from ..core.units import Units
from ..io.columns import software_name
from ..io.runs import Frame, collect_frames
from ..io.vtk import result_cells
from .figures import draw_field, field_values
from .style import field_colour_limits, field_label, field_title, frame_title, label_axes

__all__ = ["export_report", "line_profile", "report_page_count", "sample_cells"]

_A4 = (8.27, 11.69)
_A4_LANDSCAPE = (11.69, 8.27)


def _default_frames(indices: list[int], n: int = 4) -> list[int]:
    moving = [k for k in indices if k != 0] or indices
    if len(moving) <= n:
        return moving
    pick = np.unique(np.round(np.linspace(0, len(moving) - 1, n)).astype(int))
    return [moving[i] for i in pick]


def report_page_count(n_frames: int, line: bool) -> int:
    """Number of pages of a report on ``n_frames`` chosen frames."""
    return 4 + int(n_frames) + (1 if line else 0)


def _check_line(line):
    if line is None:
        return None
    try:
        x0, y0, x1, y1 = (float(v) for v in line)
    except (TypeError, ValueError):
        raise ValueError(f"line={line!r} must be four numbers (x0, y0, x1, y1) in pixels") \
            from None
    if not np.all(np.isfinite([x0, y0, x1, y1])):
        raise ValueError(f"line={line!r} must hold finite numbers")
    if x0 == x1 and y0 == y1:
        raise ValueError("line start and end are the same point; give two distinct points")
    return x0, y0, x1, y1


def line_profile(frame: Frame, units: Units, line, names=("u", "v"), n: int = 200):
    """Values of fields sampled along ``line = (x0, y0, x1, y1)`` (pixels).

    Bilinear (Q4) interpolation inside the result's cells; NaN outside them
    and in cells with an untrusted corner. Returns ``(distance, {name:
    values})`` with the distance from (x0, y0) in ``units.unit``.
    """
    x0, y0, x1, y1 = _check_line(line)
    t = np.linspace(0.0, 1.0, int(n))
    xs, ys = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
    dist = t * np.hypot(x1 - x0, y1 - y0) * units.pixel_size
    res = frame.result
    cells = result_cells(res)
    out = {}
    for name in names:
        vals = field_values(frame, name, units)
        out[name] = sample_cells(res.x, res.y, cells, vals, xs, ys)
    return dist, out


def sample_cells(x, y, cells, values, px, py, chunk: int = 256) -> np.ndarray:
    """Bilinear interpolation of nodal ``values`` at points ``(px, py)`` in
    axis-aligned Q4 cells (corners (x0,y0) (x1,y0) (x1,y1) (x0,y1)); NaN
    outside every cell."""
    px = np.asarray(px, float)
    py = np.asarray(py, float)
    out = np.full(px.shape, np.nan)
    if len(cells) == 0:
        return out
    cx0, cy0 = x[cells[:, 0]], y[cells[:, 0]]
    cx1, cy1 = x[cells[:, 2]], y[cells[:, 2]]
    for a in range(0, px.size, chunk):
        qx, qy = px[a:a + chunk, None], py[a:a + chunk, None]
        inside = (qx >= cx0) & (qx <= cx1) & (qy >= cy0) & (qy <= cy1)
        has = inside.any(axis=1)
        e = np.argmax(inside, axis=1)[has]
        i = np.nonzero(has)[0] + a
        c = cells[e]
        s = (px[i] - cx0[e]) / (cx1[e] - cx0[e])
        r = (py[i] - cy0[e]) / (cy1[e] - cy0[e])
        v = values[c]
        out[i] = ((1 - s) * (1 - r) * v[:, 0] + s * (1 - r) * v[:, 1] + s * r * v[:, 2]
                  + (1 - s) * r * v[:, 3])
    return out


def _text_page(fig, lines, y0=0.97, size=10, x=0.06):
    y = y0
    for text, kw in lines:
        fig.text(x, y, text, fontsize=kw.get("size", size), weight=kw.get("weight", "normal"),
                 va="top", family=kw.get("family", "sans-serif"))
        y -= kw.get("gap", 0.024)
    return y


def _page_parameters(fr_list, units, info, line):
    from matplotlib.figure import Figure

    fig = Figure(figsize=_A4)
    p = info["params"]
    first = fr_list[0].result
    meta = first.meta or {}
    versions = meta.get("versions") or {}
    idx = info.get("frames_all") or [f.index for f in fr_list]
    s = info.get("strain")
    lines = [("napari-aldic DIC report", {"size": 18, "weight": "bold", "gap": 0.04}),
             (f"written {_dt.datetime.now().isoformat(timespec='seconds')} by {software_name()}",
              {}),
             ("analysis software: " + (", ".join(f"{k} {v}" for k, v in versions.items())
                                       or "not recorded"), {}),
             (f"source: {info.get('source') or meta.get('inputs', {}).get('reference') or '-'}",
              {}),
             (f"frames: {len(idx)} ({idx[0]} to {idx[-1]})"
              + (f", reference mode {info['reference']}" if info.get("reference") else ""), {}),
             (f"image: {first.image_shape[1]} x {first.image_shape[0]} px; "
              f"{len(first)} nodes", {}),
             (f"units: {units.describe()}", {}),
             ("strain: " + (f"{s['measure'].replace('_', '-')} by {s['method'].replace('_', ' ')}, "
                            f"window {s['window']} nodes, virtual strain gauge "
                            f"{s['vsg_px']:g} px ({s['vsg_px'] * units.pixel_size:g} "
                            f"{units.unit})" if s else "not computed"), {}),
             ("profile line: " + ("-" if line is None else
                                  f"({line[0]:g}, {line[1]:g}) to ({line[2]:g}, {line[3]:g}) px"),
              {"gap": 0.045}),
             ("Analysis parameters (lengths in pixels)", {"size": 12, "weight": "bold",
                                                         "gap": 0.01})]
    y = _text_page(fig, lines)
    rows = [[k, "None" if v is None else str(v)] for k, v in p.to_dict().items()]
    t = meta.get("timing", {})
    if "total" in t:
        rows.append(["(time of last frame)", f"{t['total']:.3f} s"])
    ax = fig.add_axes((0.06, 0.04, 0.88, y - 0.06))
    ax.axis("off")
    table = ax.table(cellText=rows, colLabels=["parameter", "value"], loc="upper left",
                     cellLoc="left", colWidths=[0.4, 0.6])
    table.auto_set_font_size(False)
    table.set_fontsize(9)
    table.scale(1, 1.25)
    return fig


def _reason_style():
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    style = {0: ("o", (0.2, 0.6, 0.2))}
    for i, r in enumerate(Reason):
        if r != 0:
            style[int(r)] = ("x", cmap((i + 1) % 10))
    return style


def _page_mesh(fr_list, units, info, line, image):
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure

    fr = fr_list[-1]
    res, ps = fr.result, units.pixel_size
    rows, cols = res.image_shape
    fig = Figure(figsize=_A4_LANDSCAPE, layout="constrained")
    ax = fig.add_subplot()
    ext = (-0.5 * ps, (cols - 0.5) * ps, (rows - 0.5) * ps, -0.5 * ps)
    if image is not None:
        ax.imshow(np.asarray(image), cmap="gray", extent=ext, interpolation="nearest")
    elif res.roi is not None:
        ax.imshow(np.where(res.roi, 0.93, 0.6), cmap="gray", vmin=0, vmax=1, extent=ext,
                  interpolation="nearest")
    cells = result_cells(res)
    if len(cells):
        verts = np.stack([res.x[cells] * ps, res.y[cells] * ps], axis=-1)
        ax.add_collection(PolyCollection(verts, facecolors="none", edgecolors="0.45",
                                         linewidths=0.4))
    style = _reason_style()
    for code in np.unique(res.reason):
        sel = res.reason == code
        marker, color = style.get(int(code), ("x", "k"))
        ax.plot(res.x[sel] * ps, res.y[sel] * ps, linestyle="none", marker=marker,
                markersize=2.5 if code == 0 else 4, color=color,
                label=f"{Reason.describe(int(code))}: {int(sel.sum())}")
    if line is not None:
        ax.plot([line[0] * ps, line[2] * ps], [line[1] * ps, line[3] * ps], "-", color="m",
                lw=1.5, label="profile line")
    ax.set_xlim(ext[0], ext[1])
    ax.set_ylim(ext[2], ext[3])
    ax.set_aspect("equal")
    label_axes(ax, units.unit)
    p = info["params"]
    ax.set_title(f"Mesh and nodes ({frame_title(fr, units)}): {len(res)} nodes, "
                 f"{len(cells)} Q4 cells, subset {p.subset} px, step {p.step} px, "
                 f"method {p.method}", fontsize=11)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, title="node status")
    return fig


def _map_fields(has_strain: bool):
    return ("u", "v", "magnitude") + (("exx", "eyy", "exy") if has_strain else ("zncc",))


def _page_maps(fr, units, info, limits, image):
    from matplotlib.figure import Figure

    names = _map_fields(fr.strain is not None)
    rows, cols = fr.result.image_shape
    fig = Figure(figsize=_A4_LANDSCAPE if cols >= rows else _A4, layout="constrained")
    ncol = 3
    nrow = -(-len(names) // ncol)
    axes = np.atleast_1d(fig.subplots(nrow, ncol)).ravel()
    for ax, name in zip(axes, names):
        cm, lo, hi = limits[name]
        im = draw_field(ax, fr, name, units, cm, lo, hi, image=image)
        fig.colorbar(im, ax=ax, label=field_label(name, units, info), shrink=0.8)
        ax.set_title(field_title(name), fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in axes[len(names):]:
        ax.axis("off")
    res = fr.result
    fig.suptitle(f"{frame_title(fr, units)}: {res.n_valid} of {len(res)} nodes trusted",
                 fontsize=12)
    return fig


def _page_profiles(fr_list, units, info, line, limits, image):
    import matplotlib
    from matplotlib.figure import Figure

    has_strain = fr_list[-1].strain is not None
    fig = Figure(figsize=_A4, layout="constrained")
    n_plots = 2 + (3 if has_strain else 0)
    gs = fig.add_gridspec(1 + n_plots, 1, height_ratios=[2.2] + [1] * n_plots)
    ax0 = fig.add_subplot(gs[0])
    last = fr_list[-1]
    cm, lo, hi = limits["magnitude"]
    im = draw_field(ax0, last, "magnitude", units, cm, lo, hi, image=image,
                     mark_flagged=False)
    fig.colorbar(im, ax=ax0, label=field_label("magnitude", units, info), shrink=0.8)
    ps = units.pixel_size
    ax0.plot([line[0] * ps, line[2] * ps], [line[1] * ps, line[3] * ps], "-", color="m", lw=2)
    ax0.annotate("A", (line[0] * ps, line[1] * ps), color="m", weight="bold")
    ax0.annotate("B", (line[2] * ps, line[3] * ps), color="m", weight="bold")
    ax0.set_anchor("C")
    ax0.set_title(f"profile line A-B over |u|, {frame_title(last, units)}", fontsize=10)
    names = ["u", "v"] + (["exx", "eyy", "exy"] if has_strain else [])
    axes = [fig.add_subplot(gs[i + 1]) for i in range(n_plots)]
    colors = matplotlib.colormaps["viridis"](np.linspace(0, 0.9, max(len(fr_list), 1)))
    for fr, color in zip(fr_list, colors):
        dist, prof = line_profile(fr, units, line, names)
        for ax, name in zip(axes, names):
            ax.plot(dist, prof[name], color=color, lw=1.2, label=frame_title(fr, units))
    for ax, name in zip(axes, names):
        ax.set_ylabel(field_label(name, units, info).replace(" (", "\n("), fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    axes[-1].set_xlabel(f"distance from A along the line ({units.unit})")
    axes[0].legend(fontsize=7, loc="best")
    return fig


def _series(fr_list, units):
    """Mean/std over trusted nodes of each field, frame by frame."""
    names = ["u", "v"] + (["exx", "eyy", "exy"] if fr_list[0].strain is not None else [])
    stats = {n: ([], []) for n in names}
    for fr in fr_list:
        for n in names:
            v = field_values(fr, n, units)
            v = v[np.isfinite(v)]
            stats[n][0].append(v.mean() if v.size else np.nan)
            stats[n][1].append(v.std() if v.size else np.nan)
    return names, {n: (np.array(m), np.array(s)) for n, (m, s) in stats.items()}


def _page_summary(all_frames, units, info):
    from matplotlib.figure import Figure

    names, stats = _series(all_frames, units)
    idx = np.array([f.index for f in all_frames], float)
    t = idx * units.frame_interval if units.has_time else idx
    xlabel = f"time ({units.time_unit})" if units.has_time else "frame"
    fig = Figure(figsize=_A4, layout="constrained")
    gs = fig.add_gridspec(3, 1, height_ratios=[1, 1, 1.3])
    ax_d = fig.add_subplot(gs[0])
    for n in ("u", "v"):
        m, s = stats[n]
        ax_d.plot(t, m, "o-", ms=3, label=f"mean {n}")
        ax_d.fill_between(t, m - s, m + s, alpha=0.2)
    ax_d.set_ylabel(f"displacement ({units.unit})")
    ax_d.set_xlabel(xlabel)
    ax_d.legend(fontsize=8)
    ax_d.grid(alpha=0.3)
    ax_d.set_title("Mean over the trusted nodes of the ROI (band: ± 1 standard deviation)",
                   fontsize=10)
    ax_s = fig.add_subplot(gs[1])
    if "exx" in stats:
        for n in ("exx", "eyy", "exy"):
            m, s = stats[n]
            ax_s.plot(t, m, "o-", ms=3, label=f"mean {n}")
            ax_s.fill_between(t, m - s, m + s, alpha=0.2)
        s_info = info.get("strain") or {}
        ax_s.set_ylabel(f"strain ({s_info.get('measure', '').replace('_', '-')})")
        ax_s.legend(fontsize=8)
    else:
        ax_s.text(0.5, 0.5, "strain not computed", ha="center", va="center",
                  transform=ax_s.transAxes)
    ax_s.set_xlabel(xlabel)
    ax_s.grid(alpha=0.3)
    ax_t = fig.add_subplot(gs[2])
    ax_t.axis("off")
    header = ["frame"] + (["time"] if units.has_time else []) + [
        f"{n} ({units.unit})" if n in ("u", "v") else n for n in names] + ["trusted"]
    rows = []
    shown = all_frames if len(all_frames) <= 25 else all_frames[:12] + all_frames[-12:]
    for fr in shown:
        j = all_frames.index(fr)
        row = [str(fr.index)] + ([f"{t[j]:g}"] if units.has_time else [])
        row += [f"{stats[n][0][j]:.4g}" for n in names]
        row.append(f"{fr.result.n_valid}/{len(fr.result)}")
        rows.append(row)
    table = ax_t.table(cellText=rows, colLabels=header, loc="upper center", cellLoc="right")
    table.auto_set_font_size(False)
    table.set_fontsize(7)
    if len(all_frames) > 25:
        ax_t.set_title(f"first and last 12 of {len(all_frames)} frames", fontsize=8)
    fig.suptitle("Summary statistics", fontsize=13)
    return fig


def _page_validity(all_frames, units):
    from matplotlib.figure import Figure

    codes = sorted({int(c) for fr in all_frames for c in np.unique(fr.result.reason)})
    counts = np.array([[int(np.count_nonzero(fr.result.reason == c)) for c in codes]
                       for fr in all_frames])
    idx = np.array([fr.index for fr in all_frames])
    fig = Figure(figsize=_A4, layout="constrained")
    gs = fig.add_gridspec(2, 1, height_ratios=[1, 1.2])
    ax = fig.add_subplot(gs[0])
    style = _reason_style()
    bottom = np.zeros(len(all_frames))
    pos = np.arange(len(all_frames))
    for j, c in enumerate(codes):
        ax.bar(pos, counts[:, j], bottom=bottom, color=style.get(c, ("x", "k"))[1],
               label=Reason.describe(c), width=0.8)
        bottom += counts[:, j]
    step = max(1, len(pos) // 20)
    ax.set_xticks(pos[::step], [str(k) for k in idx[::step]], fontsize=7)
    ax.set_xlabel("frame")
    ax.set_ylabel("nodes")
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title("Node validity per frame (reason codes)", fontsize=10)
    ax_t = fig.add_subplot(gs[1])
    ax_t.axis("off")
    shown = list(range(len(all_frames)))
    if len(shown) > 25:
        shown = shown[:12] + shown[-12:]
    header = ["frame"] + [f"{c}: {Reason.describe(c)}" for c in codes]
    rows = [[str(idx[i])] + [str(v) for v in counts[i]] for i in shown]
    table = ax_t.table(cellText=rows, colLabels=header, loc="upper center", cellLoc="right")
    table.auto_set_font_size(False)
    table.set_fontsize(6.5 if len(codes) > 4 else 7.5)
    fig.suptitle("Validity counts", fontsize=13)
    return fig


def export_report(data, path, *, frames=None, line=None, units=None, strain=True,
                  image=None, title: str | None = None) -> Path:
    """Write a multipage PDF report of an analysis.

    Parameters
    ----------
    data : DICResult, SequenceResult, list of results, result file or run folder
    path : output ``.pdf``
    frames : list of int, optional
        Frame numbers that get a page of maps (and a profile curve). Default:
        up to four frames spread over the sequence, the last included.
    line : (x0, y0, x1, y1), optional
        Profile line in pixels of the reference image.
    units : Units or dict, optional
    strain : bool or dict of compute_strain options, default True
    image : (H, W) array, optional
        Reference image drawn under the maps.

    The report has ``4 + len(frames)`` pages, plus one with ``line``.
    """
    from matplotlib.backends.backend_pdf import PdfPages

    path = target_path(path, (".pdf",))
    line = _check_line(line)
    all_frames, units, info = collect_frames(data, strain=strain, units=units)
    if frames is None:
        chosen = _default_frames([f.index for f in all_frames])
    else:
        chosen = [int(k) for k in frames]
        missing = [k for k in chosen if k not in [f.index for f in all_frames]]
        if missing:
            raise ValueError(f"frame(s) {missing} not in the result; available: "
                             f"{[f.index for f in all_frames]}")
    shown = [f for f in all_frames if f.index in chosen]
    has_strain = shown[0].strain is not None
    limits = {}
    for name in set(_map_fields(has_strain)) | {"magnitude"}:
        limits[name] = field_colour_limits(name, [field_values(f, name, units) for f in shown])
    pages = [lambda: _page_parameters(all_frames, units, info, line),
             lambda: _page_mesh(shown, units, info, line, image)]
    pages += [lambda fr=fr: _page_maps(fr, units, info, limits, image) for fr in shown]
    if line is not None:
        pages.append(lambda: _page_profiles(shown, units, info, line, limits, image))
    pages += [lambda: _page_summary(all_frames, units, info),
              lambda: _page_validity(all_frames, units)]
    meta = {"Title": title or "napari-aldic DIC report", "Creator": software_name(),
            "Subject": f"DIC analysis, {len(all_frames)} frame(s)"}
    with atomic_write(path) as tmp:
        with PdfPages(tmp, metadata=meta) as pdf:
            for make in pages:
                fig = make()
                pdf.savefig(fig)
    return path
