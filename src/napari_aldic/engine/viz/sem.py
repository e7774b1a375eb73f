"""Figures of the SEM corrections: the scan-line shifts of each image."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.files import atomic_write
from ..core.results import DICResult

__all__ = ["scan_lines_figure", "plot_scan_lines"]


def _shifts(meta: dict, name: str) -> np.ndarray:
    out = np.zeros(int(meta["n_rows"]))
    out[np.asarray(meta[name]["rows"], int)] = meta[name]["shift_px"]
    return out


def scan_lines_figure(reference_shifts, deformed_shifts, title: str | None = None,
                      names=("reference", "deformed")):
    """A figure of the x-shift of every scan line (px) against the row, one
    panel per image."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 4.2), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    for ax, s, name in zip(axes, (reference_shifts, deformed_shifts), names):
        s = np.asarray(s, float)
        rows = np.arange(s.size)
        ax.plot(rows, s, lw=0.8, color="C0" if name == names[0] else "C3")
        ax.axhline(0.0, color="0.6", lw=0.5)
        ax.set_ylabel("shift (px)")
        n = int(np.count_nonzero(s))
        ax.set_title(f"{name}: {n} shifted line(s), largest {np.abs(s).max():.2f} px",
                     fontsize=9)
    axes[-1].set_xlabel("scan line (row)")
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def plot_scan_lines(result: DICResult, path, title: str | None = None) -> Path:
    """Write the scan-line figure of a result measured with scan-line correction
    to ``path`` (PNG)."""
    meta = result.meta.get("sem", {}).get("scan_lines")
    if meta is None:
        raise ValueError("this result holds no scan-line shifts (run with --scan-lines)")
    fig = scan_lines_figure(_shifts(meta, "reference"), _shifts(meta, "deformed"), title)
    path = Path(path)
    with atomic_write(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    return path
