"""Multipage PDF report of a DIC analysis (matplotlib ``PdfPages``, headless).

Pages, in order (see ``docs/exports.md``):

1. **Analysis**: the image files, tracking, software, units, strain settings
   and every analysis parameter as used (choices made by the analysis, such as
   the smoothing length, included).
2. **Mesh and nodes**: the nodes over the ROI, coloured by their validity
   reason (one colour per reason), with the Q4 mesh and the profile line.
3. **One page per chosen frame**: maps of u, v and |u| (physical units) and
   of exx, eyy, exy (or the ZNCC without strain), shared colour limits, laid
   out to fill the page.
4. **Line profiles** (only with ``line=(x0, y0, x1, y1)``): u, v and the
   strains sampled along the line for every chosen frame.
5. **Summary statistics** (only for more than one frame): mean and standard
   deviation over the trusted nodes of u, v and the strains against frame or
   time.
6. **Validity**: node counts per reason for every frame (with the statistics
   table for a single pair).

So a report has ``3 + len(frames)`` pages, plus one with a line and one for
a sequence (:func:`report_page_count`). :func:`report_pages` gives the
matplotlib figures themselves.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.files import atomic_write, target_path
from ..core.reasons import Reason
from ..core.units import Units
from ..io.columns import software_name
from ..io.runs import Frame, collect_frames
from ..io.vtk import result_cells
from .figures import draw_field, field_values
from .layout import A4, A4_LANDSCAPE, compact_ticks, map_grid, wrap
from .probe_page import with_probe_page
from .provenance import analysis_page
from .report_stats import profiles_page, summary_page, validity_page
from .style import (
    field_colour_limits,
    field_label,
    field_title,
    frame_title,
    label_axes,
    reason_colour,
)

__all__ = ["export_report", "report_pages", "line_profile", "report_page_count",
           "sample_cells"]


def _default_frames(indices: list[int], n: int = 4) -> list[int]:
    moving = [k for k in indices if k != 0] or indices
    if len(moving) <= n:
        return moving
    pick = np.unique(np.round(np.linspace(0, len(moving) - 1, n)).astype(int))
    return [moving[i] for i in pick]


def report_page_count(n_frames: int, line: bool = False, n_total: int | None = None) -> int:
    """Number of pages of a report with map pages for ``n_frames`` frames, out
    of ``n_total`` frames in all (default ``n_frames``): the statistics page
    against frame appears only when ``n_total > 1``."""
    n_total = int(n_frames) if n_total is None else int(n_total)
    return 3 + int(n_frames) + (1 if line else 0) + (1 if n_total > 1 else 0)


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


# =================================================================== pages
def _mesh_page(fr_list, units, info, line, image):
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure

    fr = fr_list[-1]
    res, ps = fr.result, units.pixel_size
    rows, cols = res.image_shape
    tall = rows > 1.2 * cols  # a tall image fills a portrait page, its legend below
    fig = Figure(figsize=A4 if tall else A4_LANDSCAPE, layout="constrained")
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
    for code in np.unique(res.reason):
        sel = res.reason == code
        ax.plot(res.x[sel] * ps, res.y[sel] * ps, linestyle="none",
                marker="o" if code == 0 else "x", markersize=2.5 if code == 0 else 6,
                markeredgewidth=1.0 if code == 0 else 1.8, color=reason_colour(code),
                label="\n".join(wrap(f"{int(code)}: {Reason.describe(int(code))} "
                                     f"({int(sel.sum())})", 3.2, 8)))
    if line is not None:
        ax.plot([line[0] * ps, line[2] * ps], [line[1] * ps, line[3] * ps], "-", color="m",
                lw=1.5, label="profile line")
    ax.set_xlim(ext[0], ext[1])
    ax.set_ylim(ext[2], ext[3])
    ax.set_aspect("equal")
    label_axes(ax, units.unit)
    p = info["params"]
    title = (f"Mesh and nodes, {frame_title(fr, units)}: {len(res)} nodes, {len(cells)} Q4 "
             f"cells; subset {p.subset} px, step {p.step} px, method {p.method}")
    # the figure's title, not the axes': a narrow map's title would cover its tick labels
    fig.suptitle("\n".join(wrap(title, fig.get_size_inches()[0] - 0.8, 11)), fontsize=11)
    # a figure legend "outside" gets its own room from the constrained layout
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center" if tall else
               "outside right center", ncol=2 if tall else 1, fontsize=8,
               title="node status (count)", title_fontsize=9)
    return fig


def _map_fields(has_strain: bool):
    return ("u", "v", "magnitude") + (("exx", "eyy", "exy") if has_strain else ("zncc",))


def _maps_page(fr, units, info, limits, image):
    from matplotlib.figure import Figure

    names = _map_fields(fr.strain is not None)
    res = fr.result
    size, nrow, ncol = map_grid(len(names), res.image_shape)
    fig = Figure(figsize=size, layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrow, ncol)).ravel()
    ax_w = size[0] / ncol - 1.4  # the map's own width, its colour bar beside it
    for ax, name in zip(axes, names):
        cm, lo, hi = limits[name]
        im = draw_field(ax, fr, name, units, cm, lo, hi, image=image)
        bar = fig.colorbar(im, ax=ax, shrink=0.85, aspect=25)
        bar.set_label(field_label(name, units, info), fontsize=8)
        bar.ax.tick_params(labelsize=7)
        compact_ticks(bar.ax.yaxis)
        ax.set_title("\n".join(wrap(field_title(name), max(ax_w, 1.0), 9)), fontsize=9)
        ax.tick_params(labelsize=7)
        ax.xaxis.label.set_size(8)
        ax.yaxis.label.set_size(8)
    for ax in axes[len(names):]:
        ax.axis("off")
    method = "AL-DIC" if res.params.method == "aldic" else "Local DIC"
    fig.suptitle(f"{frame_title(fr, units)}: {res.n_valid} of {len(res)} nodes trusted "
                 f"({method}; untrusted nodes blank, marked x)", fontsize=11)
    return fig


def report_pages(data, *, frames=None, line=None, units=None, strain=True, image=None):
    """The pages of :func:`export_report` as matplotlib figures, built one at a
    time (an iterator): what the PDF holds, for checks or other formats. The
    arguments are checked at once."""
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
    return _pages(all_frames, shown, units, info, line, limits, image)


def _pages(all_frames, shown, units, info, line, limits, image):
    """The figures of :func:`report_pages`, one at a time."""
    yield analysis_page(all_frames, units, info, line)
    yield _mesh_page(shown, units, info, line, image)
    for fr in shown:
        yield _maps_page(fr, units, info, limits, image)
    if line is not None:
        yield profiles_page(shown, units, info, line, limits, image,
                            lambda fr, names: line_profile(fr, units, line, names))
    if len(all_frames) > 1:
        yield summary_page(all_frames, units, info)
    yield validity_page(all_frames, units, info)


def export_report(data, path, *, frames=None, line=None, units=None, strain=True,
                  image=None, title: str | None = None, probes=None) -> Path:
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
    probes : ProbeTable, optional
        Probe values (:func:`napari_aldic.engine.probes.measure_probes`): one more
        page, last, with their curves and the stress-strain curve.

    Returns
    -------
    Path
        The PDF written. It has ``report_page_count(len(frames), line,
        n_total)`` pages: ``3 + len(frames)``, plus one with ``line`` and one
        (statistics against frame) when the data hold more than one frame
        (plus the probe page with ``probes``).
    """
    import matplotlib
    from matplotlib.backends.backend_pdf import PdfPages

    path = target_path(path, (".pdf",))
    pages = report_pages(data, frames=frames, line=line, units=units, strain=strain,
                         image=image)
    if probes is not None:
        pages = with_probe_page(pages, probes)
    meta = {"Title": title or "napari-aldic DIC report", "Creator": software_name(),
            "Subject": "DIC analysis"}
    # units, names and titles are the user's text: "$...$" in them is not mathtext
    with matplotlib.rc_context({"text.parse_math": False}), atomic_write(path) as tmp:
        with PdfPages(tmp, metadata=meta) as pdf:
            for fig in pages:
                pdf.savefig(fig)
    return path
