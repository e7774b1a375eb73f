"""Headless figures of DIC results (matplotlib only, no GUI backend).

matplotlib is imported inside the functions, so importing the engine stays
light. Figures are built on :class:`matplotlib.figure.Figure` directly, not
through ``pyplot``: no backend is selected, no window can open and no global
figure state is touched, which makes them safe in scripts, batch jobs and
worker threads.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.results import DICResult
from ..core.units import Units
from ..io.columns import frame_columns
from ..io.runs import Frame, collect_frames
from ..io.vtk import result_cells
from .layout import compact_ticks
from .style import (
    SEQUENTIAL,
    check_field,
    field_colour_limits,
    field_label,
    field_title,
    frame_title,
    label_axes,
    needs_strain,
    transparent_cmap,
    unknown_field,
)

__all__ = ["displacement_figure", "plot_displacement", "truth_at_nodes", "result_title",
           "field_figure", "field_values", "draw_field", "triangulation", "figure_size",
           "FieldSeries", "prepare_series", "frame_figure"]


def truth_at_nodes(result, truth) -> tuple[np.ndarray, np.ndarray]:
    """Exact displacement ``(u, v)`` at the nodes of ``result``.

    ``truth`` is a displacement field with a ``displacement(x, y)`` method
    (e.g. from :mod:`napari_aldic.engine.synthetic`), a callable
    ``truth(x, y) -> (u, v)``, or a pair of arrays with one value per node.
    """
    if hasattr(truth, "displacement"):
        ut, vt = truth.displacement(result.x, result.y)
    elif callable(truth):
        ut, vt = truth(result.x, result.y)
    else:
        ut, vt = truth
    ut = np.broadcast_to(np.asarray(ut, dtype=np.float64), result.x.shape)
    vt = np.broadcast_to(np.asarray(vt, dtype=np.float64), result.x.shape)
    return ut, vt


def _lattice_extent(result, ps: float = 1.0) -> tuple[float, float, float, float]:
    """imshow extent putting each lattice cell centred on its node (in units of ``ps``)."""
    xs = np.asarray(result.grid_xs, float)
    ys = np.asarray(result.grid_ys, float)
    step = float(result.params.step)
    dx = xs[1] - xs[0] if xs.size > 1 else step
    dy = ys[1] - ys[0] if ys.size > 1 else step
    return tuple(ps * e for e in (xs[0] - dx / 2, xs[-1] + dx / 2, ys[-1] + dy / 2,
                                  ys[0] - dy / 2))


def _displacement_panels(result, truth, units: Units) -> list[dict[str, Any]]:
    """The three maps of :func:`displacement_figure`: u, v and the error
    against ``truth`` (or the ZNCC without it), with colours and labels.

    u and v take their colour limits from the one rule of every export
    (:func:`~napari_aldic.engine.viz.style.field_colour_limits`): the robust
    range of the trusted values, made symmetric only when they change sign."""
    panels: list[dict[str, Any]] = []
    for name in ("u", "v"):
        grid = result.to_grid(name) * units.pixel_size
        cm, lo, hi = field_colour_limits(name, [grid])
        finite = grid[np.isfinite(grid)]
        over = finite.size and (finite.min() < lo or finite.max() > hi)
        panels.append(dict(data=grid, cmap=transparent_cmap(cm), vmin=lo, vmax=hi,
                           label=f"{name} ({units.unit})", title=f"{name} displacement",
                           extend="both" if over else "neither"))
    panels.append(_error_panel(result, truth, units) if truth is not None
                  else _zncc_panel(result))
    return panels


def _error_panel(result, truth, units: Units) -> dict[str, Any]:
    """Map of ``|(u, v) - truth|`` at the trusted nodes, capped at its 99th percentile."""
    ut, vt = truth_at_nodes(result, truth)
    err = np.hypot(result.u - ut, result.v - vt) * units.pixel_size
    sel = result.valid & np.isfinite(err)
    rmse = float(np.sqrt(np.mean(err[sel] ** 2))) if sel.any() else float("nan")
    grid = np.full(result.grid_shape, np.nan)
    grid[result.grid_iy[sel], result.grid_ix[sel]] = err[sel]
    top = float(np.percentile(err[sel], 99)) if sel.any() else 1.0
    top = top if top > 0 else 1.0
    return dict(data=grid, cmap=transparent_cmap("magma"), vmin=0.0, vmax=top,
                label=f"error |(u, v) - truth| ({units.unit})",
                title=f"error vs truth (RMSE {rmse:.4g} {units.unit})",
                extend="max" if float(np.nanmax(grid, initial=0.0)) > top else "neither")


def _zncc_panel(result) -> dict[str, Any]:
    """Map of the ZNCC of every node (untrusted ones too), from its 1st percentile
    (at most 0.99) up to 1."""
    grid = result.to_grid("zncc", invalid=None)
    finite = grid[np.isfinite(grid)]
    lo = min(float(np.percentile(finite, 1)), 0.99) if finite.size else 0.0
    clipped = finite.size and float(finite.min()) < lo
    return dict(data=grid, cmap=transparent_cmap(SEQUENTIAL), vmin=lo, vmax=1.0, label="ZNCC",
                title="correlation quality (all nodes)",
                extend="min" if clipped else "neither")


def _panel_grid(n: int, rows: int, cols: int):
    """Figure and ``n`` axes sized so that each map keeps the image aspect with
    room for its colour bar: stacked for wide images, side by side otherwise."""
    from matplotlib.figure import Figure

    if cols > 1.6 * rows:
        ax_w = 8.0
        ax_h = ax_w * rows / cols
        fig = Figure(figsize=(ax_w + 2.0, n * (ax_h + 0.8) + 0.9), layout="constrained")
        axes = fig.subplots(n, 1, sharex=True, sharey=True)
    else:
        ax_h = min(7.0, 4.2 * rows / cols)
        ax_w = ax_h * cols / rows
        fig = Figure(figsize=(n * (ax_w + 1.9), ax_h + 1.6), layout="constrained")
        axes = fig.subplots(1, n, sharex=True, sharey=True)
    return fig, np.atleast_1d(axes)


def _draw_panel(fig, ax, panel: dict[str, Any], result, image, units: Units) -> None:
    """One map on the node lattice over the optional image, flagged nodes
    marked with x, with its colour bar."""
    rows, cols = (int(s) for s in result.image_shape)
    ps = units.pixel_size
    ax.set_facecolor("0.85")
    full = (-0.5 * ps, (cols - 0.5) * ps, (rows - 0.5) * ps, -0.5 * ps)
    if image is not None:
        ax.imshow(np.asarray(image), cmap="gray", extent=full, interpolation="nearest")
    im = ax.imshow(panel["data"], cmap=panel["cmap"], vmin=panel["vmin"], vmax=panel["vmax"],
                   extent=_lattice_extent(result, ps), interpolation="nearest")
    bad = ~np.asarray(result.valid, bool)
    if bad.any():
        ax.plot(result.x[bad] * ps, result.y[bad] * ps, linestyle="none", marker="x",
                markersize=3, color="k", alpha=0.6, label="flagged node")
    ax.set_xlim(full[0], full[1])
    ax.set_ylim(full[2], full[3])
    ax.set_title(panel["title"], fontsize=10)
    label_axes(ax, units.unit)
    bar = fig.colorbar(im, ax=ax, label=panel["label"], extend=panel["extend"])
    compact_ticks(bar.ax.yaxis)


def result_title(result) -> str:
    """One line on a result: the method, nodes (trusted), subset and step."""
    p = result.params
    method = "AL-DIC" if p.method == "aldic" else "Local DIC (subset IC-GN)"
    line = (f"{method}: {len(result)} nodes ({result.n_valid} trusted), subset {p.subset} px, "
            f"step {p.step} px")
    reg = (result.meta or {}).get("regularisation") or {}
    if "smooth_px" in reg:
        line += f", smoothing {reg['smooth_px']:.1f} px"
    return line


def displacement_figure(result, truth=None, image=None, title: str | None = None,
                        units=None):
    """Figure with the u and v maps of ``result`` and an error (or ZNCC) map.

    Parameters
    ----------
    result : DICResult
        The analysis to show. Fields are drawn on the node lattice
        (``result.to_grid``), one cell per node centred on it, in the
        coordinates of the reference image; untrusted nodes are blank.
    truth : displacement field, callable or (u, v) arrays, optional
        Exact displacement (see :func:`truth_at_nodes`). When given, the
        third panel is the error magnitude ``|(u, v) - truth|``; otherwise it
        is the ZNCC of every node.
    image : (H, W) array, optional
        Reference image drawn in grey underneath (visible where there is no
        trusted node: holes, borders, flagged nodes).
    title : str, optional
        First line of the figure title; the second line always names the
        method, nodes, subset and step (:func:`result_title`).
    units : Units or dict, optional
        Lengths (axes, u, v, error) in ``units.unit``; default: the units
        stored in ``result.meta["units"]``, else pixels.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if isinstance(units, dict):
        units = Units.from_dict(units)
    units = units or Units.from_meta(result.meta) or Units()
    rows, cols = (int(s) for s in result.image_shape)
    panels = _displacement_panels(result, truth, units)
    fig, axes = _panel_grid(len(panels), rows, cols)
    for ax, panel in zip(axes, panels):
        _draw_panel(fig, ax, panel, result, image, units)
    head = result_title(result) if title is None else f"{title}\n{result_title(result)}"
    fig.suptitle(head, fontsize=11)
    return fig


def plot_displacement(result, path, truth=None, image=None, title: str | None = None,
                      dpi: int = 120, units=None) -> Path:
    """Save :func:`displacement_figure` to ``path`` (PNG, PDF, SVG... by suffix).

    Returns the path written. The figure is closed afterwards (no pyplot state).
    """
    path = Path(path)
    if not path.parent.exists():
        raise FileNotFoundError(f"folder {path.parent} does not exist; create it first")
    fig = displacement_figure(result, truth=truth, image=image, title=title, units=units)
    fig.savefig(path, dpi=dpi)
    return path

# =================================================================== field maps
def field_values(fr: Frame, name: str, units: Units) -> np.ndarray:
    """Values of field ``name`` at the nodes of one frame in ``units``; NaN
    where the node (or, for strain fields, its strain) is not trusted."""
    cols = frame_columns(fr, units)
    if name not in cols:
        if needs_strain(name) and fr.strain is None:
            raise ValueError(f"field {name!r} needs strain: export with strain=True")
        if name in ("vx", "vy") or name.endswith("_rate"):
            raise ValueError(f"field {name!r} needs a frame interval (units.frame_interval)")
        raise unknown_field(name)
    vals = np.asarray(cols[name][0], float).copy()
    ok = np.asarray(fr.result.valid, bool)
    if fr.strain is not None and needs_strain(name):
        ok = ok & np.asarray(fr.strain.valid, bool)
    vals[~ok] = np.nan
    return vals


def triangulation(res: DICResult, units: Units, values: np.ndarray):
    """matplotlib Triangulation of the result's Q4 cells (2 triangles each),
    triangles with an untrusted or NaN corner masked; None without cells."""
    from matplotlib.tri import Triangulation

    cells = result_cells(res)
    if cells.shape[0] == 0:
        return None
    tris = np.concatenate([cells[:, [0, 1, 2]], cells[:, [0, 2, 3]]])
    tri = Triangulation(res.x * units.pixel_size, res.y * units.pixel_size, tris)
    bad = ~np.isfinite(values)
    tri.set_mask(bad[tris].any(axis=1))
    return tri


def draw_field(ax, fr: Frame, name: str, units: Units, cmap, vmin, vmax, image=None,
               mark_flagged: bool = True):
    """Draw one field of one frame on ``ax``; returns the colour mappable."""
    import matplotlib

    res, ps = fr.result, units.pixel_size
    rows, cols = (int(s) for s in res.image_shape)
    vals = field_values(fr, name, units)
    ax.set_facecolor("0.88")
    if image is not None:
        ax.imshow(np.asarray(image), cmap="gray",
                  extent=(-0.5 * ps, (cols - 0.5) * ps, (rows - 0.5) * ps, -0.5 * ps),
                  interpolation="nearest")
    cm = matplotlib.colormaps[cmap] if isinstance(cmap, str) else cmap
    tri = triangulation(res, units, vals)
    if tri is not None and not tri.mask.all():
        shown = np.where(np.isfinite(vals), vals, 0.0)
        im = ax.tripcolor(tri, shown, shading="gouraud", cmap=cm, vmin=vmin, vmax=vmax,
                          rasterized=True)
    else:
        ok = np.isfinite(vals)
        im = ax.scatter(res.x[ok] * ps, res.y[ok] * ps, c=vals[ok], cmap=cm, vmin=vmin,
                        vmax=vmax, s=12, marker="s")
        if not ok.any():
            im = matplotlib.cm.ScalarMappable(norm=matplotlib.colors.Normalize(vmin, vmax),
                                              cmap=cm)
    bad = ~np.asarray(res.valid, bool)
    if mark_flagged and bad.any():
        ax.plot(res.x[bad] * ps, res.y[bad] * ps, linestyle="none", marker="x", markersize=3,
                color="k", alpha=0.5)
    ax.set_xlim(-0.5 * ps, (cols - 0.5) * ps)
    ax.set_ylim((rows - 0.5) * ps, -0.5 * ps)
    ax.set_aspect("equal")
    label_axes(ax, units.unit)
    return im


def figure_size(shape, width: float = 6.4) -> tuple[float, float]:
    """Figure size (inches) for a map of an image of ``shape`` with a colour bar."""
    rows, cols = shape
    ax_w = width - 1.8  # room for the colour bar
    ax_h = max(2.0, min(8.0, ax_w * rows / max(cols, 1)))
    return width, ax_h + 1.1


@dataclass
class FieldSeries:
    """Frames of one field prepared for a series of maps (PNG files, GIF, MP4)
    with shared colour limits: the output of :func:`prepare_series`."""

    frames: list[Frame]
    field: str
    units: Units
    info: dict
    cmap: str
    vmin: float
    vmax: float


def prepare_series(data, field: str, frames, units, strain, clim) -> FieldSeries:
    """Collect the frames of ``data`` and the colour limits they share
    (:func:`~napari_aldic.engine.viz.style.field_colour_limits`)."""
    check_field(field)
    fr_list, units, info = collect_frames(data, frames=frames, strain=strain, units=units)
    values = [field_values(fr, field, units) for fr in fr_list]
    cm, lo, hi = field_colour_limits(field, values, clim)
    return FieldSeries(list(fr_list), field, units, info, cm, lo, hi)


def frame_figure(series: FieldSeries, fr: Frame, *, image=None, cmap=None,
                 title: str | None = None):
    """The figure of one frame of a :class:`FieldSeries` (see :func:`field_figure`)."""
    from matplotlib.figure import Figure

    field, units = series.field, series.units
    fig = Figure(figsize=figure_size(fr.result.image_shape), dpi=100, layout="constrained")
    ax = fig.add_subplot()
    im = draw_field(ax, fr, field, units, cmap or series.cmap, series.vmin, series.vmax,
                    image=image)
    bar = fig.colorbar(im, ax=ax, label=field_label(field, units, series.info), shrink=0.9)
    compact_ticks(bar.ax.yaxis)
    ax.set_title(title or f"{field_title(field)} - {frame_title(fr, units)}", fontsize=10)
    return fig


def field_figure(data, field: str = "u", *, frame: int | None = None, units=None,
                 strain=True, image=None, cmap=None, clim=None, title: str | None = None):
    """A matplotlib Figure of one field of one frame, with a labelled colour bar.

    ``frame`` is a frame number (default: the last). Untrusted nodes are left
    blank and marked with x. Built on ``matplotlib.figure.Figure`` (no pyplot,
    no GUI backend).
    """
    fr_list, units, info = collect_frames(
        data, frames=None if frame is None else [frame], strain=strain, units=units)
    fr = fr_list[-1]
    cm, lo, hi = field_colour_limits(field, [field_values(fr, field, units)], clim)
    series = FieldSeries([fr], field, units, info, cm, lo, hi)
    return frame_figure(series, fr, image=image, cmap=cmap, title=title)
