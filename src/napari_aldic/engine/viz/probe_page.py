"""Pictures of probe values (matplotlib, headless): curves over frames, the
stress-strain curve, kymographs, and the probe page of the PDF report.

The functions read a probe table and a kymograph by their attributes only
(``frames``, ``columns[name].values/.unit/.status``, ``units``; see
:class:`napari_aldic.engine.probes.ProbeTable` and
:class:`~napari_aldic.engine.probes.Kymograph`), so this layer does not import the
probes package. Missing values are gaps, degraded ones hollow markers.
"""

from __future__ import annotations

import numpy as np

__all__ = ["draw_probe_curves", "draw_stress_strain", "draw_kymograph", "default_plot_columns",
           "probe_figure", "probe_page", "stress_strain_column", "with_probe_page"]

_A4 = (8.27, 11.69)
DEGRADED = 1


def default_plot_columns(table) -> list[str]:
    """The columns a figure shows by default: gauge strains, crack opening and
    sliding, point values, area means and the load."""
    out = []
    for name in table.columns:
        if name.startswith("line") and not name.endswith(("_strain", "_cod_opening",
                                                           "_cod_sliding")):
            continue
        if name.endswith("_true_strain"):
            continue
        if name.startswith("area") and not name.endswith("_mean"):
            continue
        if name == "stress_MPa":
            continue
        out.append(name)
    return out


def stress_strain_column(table) -> str | None:
    """The strain of the stress-strain curve: the first line gauge's strain."""
    if "stress_MPa" not in table.columns:
        return None
    return next((n for n in table.columns if n.startswith("line") and n.endswith("_strain")
                 and not n.endswith("_true_strain")), None)


def _x(table, time: bool):
    if time and getattr(table, "times", None) is not None:
        return np.asarray(table.times, float), f"time [{table.units.time_unit}]"
    return np.asarray(table.frames, float), "frame"


def _label(col) -> str:
    return f"{col.name} [{col.unit}]" if col.unit else col.name


def draw_probe_curves(ax, table, names, *, current=None, time: bool = False) -> list:
    """Curves of the columns ``names`` over the frames; ``current`` (a frame
    number) is marked by a vertical line. Returns the line artists."""
    x, xlabel = _x(table, time)
    lines = []
    for name in names:
        col = table.columns[name]
        (ln,) = ax.plot(x, col.values, marker="o", ms=3.5, lw=1.4, label=_label(col))
        deg = np.asarray(col.status) == DEGRADED
        if deg.any():
            ax.plot(x[deg], col.values[deg], ls="none", marker="o", ms=8, mfc="none",
                    mec=ln.get_color(), mew=1.2)
        lines.append(ln)
    if current is not None:
        xc = float(current) * (table.units.frame_interval if time and table.times is not None
                               else 1.0)
        ax.axvline(xc, color="0.35", lw=1.0, ls="--", zorder=0)
    ax.set_xlabel(xlabel)
    if xlabel == "frame":
        from matplotlib.ticker import MaxNLocator

        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    units = sorted({table.columns[n].unit for n in names})
    ax.set_ylabel(", ".join(u or "dimensionless" for u in units))
    ax.grid(True, alpha=0.3)
    if lines:
        ax.legend(fontsize=7, loc="best")
    return lines


def draw_stress_strain(ax, table, strain: str | None = None, *, current=None) -> list:
    """Engineering stress against the gauge strain ``strain`` (default: the first
    line gauge), ``current`` frame marked."""
    strain = strain or stress_strain_column(table)
    if strain is None or "stress_MPa" not in table.columns:
        ax.text(0.5, 0.5, "stress-strain: needs load data and a line gauge", ha="center",
                va="center", transform=ax.transAxes, color="0.4")
        ax.set_axis_off()
        return []
    e, s = table.columns[strain].values, table.columns["stress_MPa"].values
    (ln,) = ax.plot(e, s, marker="o", ms=3.5, lw=1.4, color="C3", label=strain.split("_")[0])
    deg = np.asarray(table.columns[strain].status) == DEGRADED
    if deg.any():  # the gauge's values read with care: another marker and colour
        ax.plot(e[deg], s[deg], ls="none", marker="s", ms=6, mfc="none", mec="C1", mew=1.4,
                label="degraded")
    ax.legend(fontsize=7, loc="best")
    if current is not None and current in list(table.frames):
        i = list(table.frames).index(current)
        ax.plot([e[i]], [s[i]], marker="o", ms=10, mfc="none", mec="k", mew=1.5)
    ax.set_xlabel(f"{strain} (engineering strain)")
    ax.set_ylabel("engineering stress [MPa]")
    ax.set_title("stress-strain", fontsize=10)
    ax.grid(True, alpha=0.3)
    return [ln]


def draw_kymograph(ax, kymo, *, cmap: str | None = None):
    """Image of ``kymo.values`` (frames down, distance along the line across)."""
    vals = np.asarray(kymo.values, float)
    fin = vals[np.isfinite(vals)]
    lim = float(np.max(np.abs(fin))) if fin.size else 1.0
    sym = fin.size and fin.min() < 0 < fin.max()
    d, f = np.asarray(kymo.distance, float), np.asarray(kymo.frames, float)
    extent = (d[0], d[-1], f[-1] + 0.5, f[0] - 0.5)
    im = ax.imshow(vals, aspect="auto", extent=extent, interpolation="nearest",
                   cmap=cmap or ("RdBu_r" if sym else "viridis"),
                   vmin=-lim if sym else None, vmax=lim if sym else None)
    ax.set_xlabel(f"distance along the line [{kymo.units.unit}]")
    ax.set_ylabel("frame")
    cb = ax.figure.colorbar(im, ax=ax)
    cb.set_label(f"{kymo.field} [{kymo.unit}]" if kymo.unit else kymo.field)
    return im


def _panels(table, columns) -> list[list[str]]:
    """Columns grouped by unit, one panel each (load on its own)."""
    groups: dict = {}
    for n in columns:
        key = "load" if n in ("load_N",) else table.columns[n].unit
        groups.setdefault(key, []).append(n)
    return list(groups.values())


def probe_figure(table, columns=None, *, current=None, figsize=None, time: bool = False):
    """A figure of probe curves: one panel per unit, and the stress-strain curve
    when the table has load data."""
    from matplotlib.figure import Figure

    columns = default_plot_columns(table) if columns is None else list(columns)
    panels = _panels(table, columns)
    ss = stress_strain_column(table)
    n = max(1, len(panels) + (ss is not None))
    fig = Figure(figsize=figsize or (7.5, 2.4 * n + 0.6), layout="constrained")
    axes = fig.subplots(n, 1, squeeze=False)[:, 0]
    for ax, names in zip(axes, panels):
        draw_probe_curves(ax, table, names, current=current, time=time)
        if ax is not axes[0]:
            ax.sharex(axes[0])  # a frame without a value shows as a gap, not a shorter axis
    if ss is not None:
        draw_stress_strain(axes[len(panels)], table, ss, current=current)
    if not panels and ss is None:
        axes[0].text(0.5, 0.5, "no probe", ha="center", va="center")
        axes[0].set_axis_off()
    return fig


def _probe_lines(table) -> list[str]:
    out = []
    for label, p in table.probes.labels():
        d = p.to_dict()
        where = d.get("xy") if "xy" in d else f"{d['shape']} {d['params']}"
        out.append(f"{label}{' (' + p.name + ')' if p.name else ''}: {where}")
    return out


def probe_page(table):
    """The report's probe page: the probe positions (reference pixels), their
    curves and the stress-strain curve."""
    fig = probe_figure(table, figsize=_A4)
    fig.suptitle("Probes (reference-image pixels; lengths in "
                 f"{table.units.unit}; hollow markers: degraded values)", fontsize=11)
    text = "; ".join(_probe_lines(table))
    if len(text) > 400:
        text = text[:397] + "..."
    notes = [text, *table.status_summary()[:6]]
    fig.get_layout_engine().set(rect=(0, 0.02 + 0.012 * len(notes), 1,
                                      0.98 - 0.012 * len(notes)))
    fig.text(0.02, 0.01, "\n".join(notes), fontsize=6.5, wrap=True, va="bottom")
    return fig


def with_probe_page(pages, table):
    """The figures of ``pages`` (an iterable), then the probe page of ``table``."""
    yield from pages
    yield probe_page(table)
