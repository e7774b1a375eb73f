"""The report pages after the maps: line profiles, statistics against frame,
and node validity (see :mod:`~napari_aldic.engine.viz.report`).

Pages with tables are laid out by hand (fixed axes boxes in figure
fractions) so that a table always gets the room it is given; the others use
matplotlib's constrained layout.
"""

from __future__ import annotations

import numpy as np

from ..core.reasons import Reason
from .figures import draw_field, field_values
from .layout import A4, compact_ticks, fit_table
from .style import field_label, frame_title, reason_colour

__all__ = ["profiles_page", "summary_page", "validity_page", "frame_statistics"]

#: most table rows of a page: the first and last frames of longer sequences
_MAX_ROWS = 24


def _measure(info) -> str:
    s = (info or {}).get("strain") or {}
    return s.get("measure", "").replace("_", "-")


def _short_label(name: str, units) -> str:
    """Axis label of a profile or series: ``u (mm)``; strains are dimensionless."""
    return f"{name} ({units.unit})" if name in ("u", "v") else name


# =================================================================== profiles
def profiles_page(fr_list, units, info, line, limits, image, profile):
    """|u| map with the line A-B, then u, v (and strains) along it for every
    chosen frame. ``profile(frame, names)`` gives ``(distance, {name: values})``."""
    import matplotlib
    from matplotlib.figure import Figure

    last = fr_list[-1]
    has_strain = last.strain is not None
    names = ["u", "v"] + (["exx", "eyy", "exy"] if has_strain else [])
    fig = Figure(figsize=A4, layout="constrained")
    gs = fig.add_gridspec(1 + len(names), 1, height_ratios=[2.4] + [1] * len(names))
    ax0 = fig.add_subplot(gs[0])
    cm, lo, hi = limits["magnitude"]
    im = draw_field(ax0, last, "magnitude", units, cm, lo, hi, image=image, mark_flagged=False)
    bar = fig.colorbar(im, ax=ax0, shrink=0.85)
    bar.set_label(field_label("magnitude", units, info), fontsize=8)
    compact_ticks(bar.ax.yaxis)
    ps = units.pixel_size
    ax0.plot([line[0] * ps, line[2] * ps], [line[1] * ps, line[3] * ps], "-", color="m", lw=2)
    for tag, (x, y) in (("A", line[:2]), ("B", line[2:])):
        ax0.annotate(tag, (x * ps, y * ps), color="m", weight="bold", xytext=(3, 3),
                     textcoords="offset points")
    ax0.set_title(f"profile line A-B over |u|, {frame_title(last, units)}", fontsize=10)
    ax0.tick_params(labelsize=7)
    axes = [fig.add_subplot(gs[i + 1]) for i in range(len(names))]
    colors = matplotlib.colormaps["viridis"](np.linspace(0, 0.9, max(len(fr_list), 1)))
    for fr, color in zip(fr_list, colors):
        dist, prof = profile(fr, names)
        for ax, name in zip(axes, names):
            ax.plot(dist, prof[name], color=color, lw=1.2, label=frame_title(fr, units))
    for ax, name in zip(axes, names):
        ax.set_ylabel(_short_label(name, units), fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
        compact_ticks(ax.yaxis, 4)
        if ax is not axes[-1]:
            ax.tick_params(labelbottom=False)
        ax.sharex(axes[0])
    axes[-1].set_xlabel(f"distance from A along the line ({units.unit})", fontsize=8)
    axes[0].legend(fontsize=7, loc="lower left", bbox_to_anchor=(0.0, 1.02),
                   ncol=min(len(fr_list), 4), frameon=False)
    fig.align_ylabels(axes)
    note = f"; strains {_measure(info)}, dimensionless" if has_strain else ""
    fig.suptitle(f"Line profiles (bilinear in the Q4 cells; gaps: no trusted material){note}",
                 fontsize=10)
    return fig


# =================================================================== statistics
def frame_statistics(fr, names, units) -> dict[str, tuple[float, float, float, float, int]]:
    """``name -> (mean, std, min, max, count)`` over the trusted nodes of a frame."""
    out = {}
    for n in names:
        v = field_values(fr, n, units)
        v = v[np.isfinite(v)]
        out[n] = ((float(v.mean()), float(v.std()), float(v.min()), float(v.max()), v.size)
                  if v.size else (np.nan, np.nan, np.nan, np.nan, 0))
    return out


def quality_rows(fr, units) -> list[list[str]]:
    """Table rows on measurement quality: the predicted standard uncertainty
    and SSSIG over the trusted nodes, and the noise floor of a static pair
    (``meta["noise_floor"]``) when one was measured."""
    rows = []
    names = [n for n in ("u_std", "v_std", "sssig") if getattr(fr.result, n, None) is not None]
    stats = frame_statistics(fr, names, units)
    for n in names:
        if stats[n][4]:
            label = f"{n} ({units.unit})" if n.endswith("_std") else "SSSIG (GL²)"
            rows.append([label] + [f"{v:.4g}" for v in stats[n][:4]] + [str(stats[n][4])])
    nf = fr.result.meta.get("noise_floor")
    if nf:
        ps = units.pixel_size
        for key, label, scale in (("u_std_px", f"noise floor u ({units.unit})", ps),
                                  ("v_std_px", f"noise floor v ({units.unit})", ps),
                                  ("exx_std", "noise floor exx", 1.0),
                                  ("eyy_std", "noise floor eyy", 1.0),
                                  ("exy_std", "noise floor exy", 1.0)):
            if key in nf:
                rows.append([label, "0", f"{nf[key] * scale:.4g}", "", "",
                             str(nf.get("n_valid", ""))])
    return rows


def _names(frames) -> list[str]:
    return ["u", "v"] + (["exx", "eyy", "exy"] if frames[-1].strain is not None else [])


def _shown(items: list) -> list:
    """All items, or the first and last ones when there are too many for a table."""
    if len(items) <= _MAX_ROWS:
        return list(items)
    half = _MAX_ROWS // 2
    return items[:half] + items[-half:]


def _series_axes(fig, rect, t, stats, names, xlabel, ylabel):
    ax = fig.add_axes(rect)
    for n in names:
        m = np.array([s[n][0] for s in stats])
        sd = np.array([s[n][1] for s in stats])
        ax.plot(t, m, "o-", ms=3, label=f"mean {n}")
        ax.fill_between(t, m - sd, m + sd, alpha=0.2)
    ax.set_xlabel(xlabel, fontsize=8)
    ax.set_ylabel(ylabel, fontsize=8)
    ax.tick_params(labelsize=7)
    compact_ticks(ax.yaxis, 5)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return ax


def summary_page(frames, units, info):
    """Mean +- standard deviation over the trusted nodes against frame or time,
    and the table of the means."""
    from matplotlib.figure import Figure

    names = _names(frames)
    stats = [frame_statistics(fr, names, units) for fr in frames]
    idx = np.array([f.index for f in frames], float)
    t = idx * units.frame_interval if units.has_time else idx
    xlabel = f"time ({units.time_unit})" if units.has_time else "frame"
    fig = Figure(figsize=A4)
    fig.text(0.5, 0.975, "Summary statistics over the trusted nodes of the ROI "
             "(band: ± 1 standard deviation)", ha="center", va="top", fontsize=11)
    header = ["frame"] + (["time"] if units.has_time else []) + \
        [f"mean {_short_label(n, units)}" for n in names] + ["trusted"]
    rows = []
    for j in _shown(list(range(len(frames)))):
        fr = frames[j]
        row = [str(fr.index)] + ([f"{t[j]:g}"] if units.has_time else [])
        row += [f"{stats[j][n][0]:.4g}" for n in names]
        rows.append(row + [f"{fr.result.n_valid}/{len(fr.result)}"])
    groups = [(["u", "v"], f"displacement ({units.unit})")]
    if "exx" in names:
        groups.append((["exx", "eyy", "exy"], f"strain ({_measure(info)})"))
    gap = 0.075  # room for the tick and axis labels under each plot
    room = 0.935 - 0.05 - _table_height(fig, rows, len(frames)) - gap
    h = min(0.3, (room - (len(groups) - 1) * gap) / len(groups))
    y = 0.935
    for which, ylabel in groups:
        y -= h
        _series_axes(fig, (0.12, y, 0.68, h), t, stats, which, xlabel, ylabel)
        y -= gap
    _table_box(fig, header, rows, len(frames), y - 0.01)
    return fig


def _table_height(fig, rows, n_frames: int, fontsize: float = 7.5) -> float:
    """Figure fraction that :func:`_table_box` needs for ``rows``."""
    row = 1.75 * fontsize / 72.0 / fig.get_size_inches()[1]
    return (len(rows) + 1.3) * row + (0.02 if n_frames > _MAX_ROWS else 0.0)


def _table_box(fig, header, rows, n_frames: int, top: float, fontsize: float = 7.5) -> None:
    """Draw the table of a statistics page with its top edge at ``top`` (figure
    fraction), just as high as its rows need."""
    height = _table_height(fig, rows, n_frames, fontsize)
    if n_frames > _MAX_ROWS:
        fig.text(0.07, top - 0.015, f"first and last {_MAX_ROWS // 2} of {n_frames} frames",
                 fontsize=8, va="center")
        top -= 0.02
        height -= 0.02
    ax = fig.add_axes((0.07, max(top - height, 0.02), 0.86, min(height, top - 0.02)))
    fit_table(ax, header, rows, [1.0 / len(header)] * len(header), fontsize=fontsize)


# =================================================================== validity
def _counts(frames):
    codes = sorted({int(c) for fr in frames for c in np.unique(fr.result.reason)})
    counts = np.array([[int(np.count_nonzero(fr.result.reason == c)) for c in codes]
                       for fr in frames])
    return codes, counts


def _reason_handles(codes):
    from matplotlib.patches import Patch

    return [Patch(color=reason_colour(c), label=f"{c}: {Reason.describe(c)}") for c in codes]


def validity_page(frames, units, info):
    """Node counts per reason code: stacked bars and a table for a sequence;
    bars per reason and the statistics table for a single frame."""
    if len(frames) == 1:
        return _validity_single(frames[0], units, info)
    from matplotlib.figure import Figure

    codes, counts = _counts(frames)
    idx = np.array([fr.index for fr in frames])
    fig = Figure(figsize=A4)
    fig.text(0.5, 0.975, "Node validity per frame (reason codes)", ha="center", va="top",
             fontsize=11)
    header = ["frame"] + [f"code {c}" for c in codes] + ["trusted %"]
    rows = [[str(idx[i])] + [str(v) for v in counts[i]]
            + [f"{100.0 * frames[i].result.n_valid / max(len(frames[i].result), 1):.1f}"]
            for i in _shown(list(range(len(frames))))]
    legend_h = (-(-len(codes) // 2)) * 1.5 * 7.5 / 72.0 / fig.get_size_inches()[1]
    under = 0.06 + legend_h + 0.02  # frame numbers, axis label, the legend, a gap
    h = min(0.45, 0.935 - 0.03 - _table_height(fig, rows, len(frames)) - under)
    ax = fig.add_axes((0.1, 0.935 - h, 0.85, h))
    pos = np.arange(len(frames))
    bottom = np.zeros(len(frames))
    for j, c in enumerate(codes):
        ax.bar(pos, counts[:, j], bottom=bottom, color=reason_colour(c), width=0.8)
        bottom += counts[:, j]
    step = max(1, -(-len(pos) // 15))
    ax.set_xticks(pos[::step], [str(k) for k in idx[::step]], fontsize=7)
    ax.tick_params(labelsize=7)
    ax.set_xlabel("frame", fontsize=8)
    ax.set_ylabel("nodes", fontsize=8)
    fig.legend(handles=_reason_handles(codes), loc="upper center", ncol=2, fontsize=7.5,
               bbox_to_anchor=(0.5, 0.935 - h - 0.06), frameon=False)
    _table_box(fig, header, rows, len(frames), 0.935 - h - under)
    return fig


def _validity_single(fr, units, info):
    from matplotlib.figure import Figure

    codes, counts = _counts([fr])
    fig = Figure(figsize=A4)
    fig.text(0.5, 0.975, f"Node validity and statistics, {frame_title(fr, units)}",
             ha="center", va="top", fontsize=11)
    ax = fig.add_axes((0.45, 0.72, 0.47, 0.2))
    pos = np.arange(len(codes))
    ax.barh(pos, counts[0], color=[reason_colour(c) for c in codes])
    ax.set_yticks(pos, [f"{c}: {Reason.describe(c)}" for c in codes], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("nodes", fontsize=8)
    ax.tick_params(axis="x", labelsize=7)
    for p, n in zip(pos, counts[0]):
        ax.annotate(f"{n}", (n, p), xytext=(3, 0), textcoords="offset points", va="center",
                    fontsize=7)
    ax.set_xlim(0, counts.max() * 1.18)
    names = _names([fr])
    stats = frame_statistics(fr, names, units)
    rows = [[_short_label(n, units)] + [f"{v:.4g}" for v in stats[n][:4]] + [str(stats[n][4])]
            for n in names] + quality_rows(fr, units)
    fig.text(0.07, 0.62, "Statistics over the trusted nodes"
             + (f" (strain: {_measure(info)})" if "exx" in names else ""), fontsize=10)
    tab = fig.add_axes((0.07, 0.05, 0.86, 0.55))
    fit_table(tab, ["field", "mean", "std", "min", "max", "nodes"], rows,
              [0.2, 0.16, 0.16, 0.16, 0.16, 0.16], fontsize=8)
    return fig
