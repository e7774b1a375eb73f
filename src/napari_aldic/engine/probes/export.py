"""Profile/kymograph CSV files and probe plots (PNG or PDF)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..core.files import atomic_write, target_path
from ..io.columns import software_name
from ..viz.probe_page import draw_kymograph, probe_figure
from .measure import Kymograph
from .table import ProbeTable

__all__ = ["export_kymograph_csv", "export_probe_plot", "export_kymograph_plot"]

PLOT_SUFFIXES = (".png", ".pdf")


def export_kymograph_csv(kymo: Kymograph, path) -> Path:
    """Write a profile / kymograph: one row per point along the line.

    A plain table: the header is ``distance [unit]``, ``x_px [px]``, ``y_px [px]``
    and one column per frame, ``frame_<k> [field unit]``; missing values are
    empty cells. What describes it (software, field, units, coordinates) goes
    to ``NAME.json`` beside it.
    """
    path = target_path(path, (".csv", ".txt"))
    unit = f" [{kymo.unit}]" if kymo.unit else " [1]"
    header = [f"distance [{kymo.units.unit}]", "x_px [px]", "y_px [px]"]
    header += [f"frame_{int(k)}{unit}" for k in kymo.frames]
    lines = [",".join(header)]
    for j in range(kymo.x.size):
        cells = [f"{kymo.distance[j]:.10g}", f"{kymo.x[j]:.10g}", f"{kymo.y[j]:.10g}"]
        cells += ["" if not np.isfinite(v) else f"{v:.10g}" for v in kymo.values[:, j]]
        lines.append(",".join(cells))
    meta = {"software": software_name(), "csv": path.name,
            "content": "profile along a line: one row per point, one column per frame",
            "field": kymo.field, "field_unit": kymo.unit or "1",
            "settings": kymo.units.to_dict(), "header": header,
            "coordinates": "reference-image pixels (x = column, y = row); empty cell = no "
                           "trusted value there"}
    with atomic_write(path.with_suffix(".json")) as tmp:
        tmp.write_text(json.dumps(meta, indent=1, ensure_ascii=False), encoding="utf-8")
    with atomic_write(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _save(fig, path: Path, dpi: int) -> Path:
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format=path.suffix[1:].lower(), dpi=dpi)
    return path


def export_probe_plot(table: ProbeTable, path, *, columns=None, dpi: int = 150,
                      time: bool = False) -> Path:
    """Curves of the probe columns over the frames (and the stress-strain curve
    with load data) as PNG or PDF (by the suffix; PNG when it has none)."""
    path = target_path(path, PLOT_SUFFIXES)
    return _save(probe_figure(table, columns, time=time), path, dpi)


def export_kymograph_plot(kymo: Kymograph, path, *, dpi: int = 150) -> Path:
    """The kymograph as an image (PNG or PDF)."""
    from matplotlib.figure import Figure

    path = target_path(path, PLOT_SUFFIXES)
    fig = Figure(figsize=(7.0, 4.2), layout="constrained")
    ax = fig.subplots()
    draw_kymograph(ax, kymo)
    ax.set_title(f"kymograph of {kymo.field}", fontsize=10)
    return _save(fig, path, dpi)
