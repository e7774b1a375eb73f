"""Page geometry shared by the PDF report and the figures: A4 pages, tables that
fit their box, wrapped text lines, and the grid of maps that fills a page.

Nothing here imports matplotlib at module level. Every size is in inches
unless said otherwise; font sizes are in points.
"""

from __future__ import annotations

import textwrap

import numpy as np

__all__ = ["A4", "A4_LANDSCAPE", "wrap", "clip", "text_lines", "fit_table", "map_grid",
           "compact_ticks"]

A4 = (8.27, 11.69)
A4_LANDSCAPE = (11.69, 8.27)
#: average width of a DejaVu Sans character, in units of the font size
_CHAR_EM = 0.6


def chars_for(width_in: float, fontsize: float) -> int:
    """How many characters of ``fontsize`` fit in ``width_in`` inches (a safe estimate)."""
    return max(4, int(width_in * 72.0 / (fontsize * _CHAR_EM)))


def wrap(text: str, width_in: float, fontsize: float) -> list[str]:
    """``text`` broken into lines that fit ``width_in`` inches (long words, such
    as file paths, are broken too)."""
    return textwrap.wrap(str(text), chars_for(width_in, fontsize), break_on_hyphens=False) \
        or [""]


def clip(text: str, n: int) -> str:
    """``text`` cut to ``n`` characters, the cut marked with an ellipsis."""
    text = str(text)
    return text if len(text) <= n else text[:max(n - 1, 1)] + "…"


def text_lines(fig, lines, *, top: float = 0.96, left: float = 0.07,
               width_in: float | None = None) -> float:
    """Write ``(text, style)`` lines down the page from ``top`` (figure fraction),
    wrapping each to the page width; returns the figure fraction below the last.

    ``style`` may set ``size`` (points, default 9.5), ``weight`` and
    ``space`` (extra space after the line, in line heights).
    """
    fig_w, fig_h = fig.get_size_inches()
    width_in = width_in or fig_w * (1 - 2 * left)
    y = top
    for text, style in lines:
        size = style.get("size", 9.5)
        step = 1.45 * size / 72.0 / fig_h  # one line height as a figure fraction
        for part in wrap(text, width_in, size):
            fig.text(left, y, part, fontsize=size, weight=style.get("weight", "normal"),
                     va="top", ha="left")
            y -= step
        y -= style.get("space", 0.25) * step
    return y


def fit_table(ax, header, rows, col_widths, *, fontsize: float = 8.0,
              align=None, row_in: float | None = None):
    """A table at the top of ``ax`` (its axis switched off) whose cells never
    overflow: every cell's text is cut to its column width.

    ``col_widths`` are fractions of the axes width; ``align`` gives ``"left"``,
    ``"right"`` or ``"center"`` per column (default: first column left, the
    rest right); ``row_in`` is the row height in inches (default 1.75 lines of
    the font). Rows that do not fit the axes are left out (the caller shows a
    selection); returns the table.
    """
    fig = ax.get_figure()
    ax.axis("off")
    pos = ax.get_position()
    ax_w = pos.width * fig.get_size_inches()[0]
    ax_h = pos.height * fig.get_size_inches()[1]
    row_in = row_in or 1.75 * fontsize / 72.0
    n_fit = max(1, int(ax_h / row_in) - 1)
    rows = [list(r) for r in rows[:n_fit]]
    limits = [chars_for(w * ax_w - 0.08, fontsize) for w in col_widths]
    header = [clip(h, n) for h, n in zip(header, limits)]
    cells = [[clip(c, n) for c, n in zip(r, limits)] for r in rows]
    align = align or (["left"] + ["right"] * (len(header) - 1))
    height = min(1.0, row_in * (len(cells) + 1) / ax_h)
    table = ax.table(cellText=cells or None, colLabels=header, colWidths=list(col_widths),
                     bbox=(0.0, 1.0 - height, sum(col_widths), height))
    table.auto_set_font_size(False)
    table.set_fontsize(fontsize)
    for (r, c), cell in table.get_celld().items():
        cell.set_linewidth(0.4)
        cell.get_text().set_horizontalalignment(align[c] if r > 0 else "center")
        cell.PAD = 0.03
        if r == 0:
            cell.set_facecolor("0.92")
            cell.get_text().set_weight("bold")
    return table


def map_grid(n: int, shape, *, reserve_in: float = 1.2,
             bar_in: float = 0.9) -> tuple[tuple[float, float], int, int]:
    """``(page size, rows, columns)`` that draw ``n`` maps of an image of
    ``shape = (rows, cols)`` largest on an A4 page (portrait or landscape).

    Each map needs its own width plus ``bar_in`` for its colour bar and
    labels; each row of maps needs ``reserve_in`` of height for the title,
    tick and axis labels.
    """
    rows_px, cols_px = (max(int(s), 1) for s in shape)
    aspect = rows_px / cols_px
    best = None
    for page in (A4, A4_LANDSCAPE):
        usable_w, usable_h = page[0] - 0.6, page[1] - 1.0  # margins and the page title
        for ncol in range(1, n + 1):
            nrow = -(-n // ncol)
            w = usable_w / ncol - bar_in - 0.5  # 0.5: the y tick labels
            h = usable_h / nrow - reserve_in
            side = min(w, h / aspect)
            if side <= 0:
                continue
            score = side * side * aspect
            if best is None or score > best[0] * 1.02:  # prefer portrait on a near tie
                best = (score, page, nrow, ncol)
    if best is None:
        return A4, n, 1
    return best[1], best[2], best[3]


def compact_ticks(axis, nbins: int = 5) -> None:
    """At most ``nbins`` ticks on ``axis`` labelled without an offset or a
    separate ``1e-5`` multiplier (those float above the axes, over titles)."""
    from matplotlib.ticker import Formatter, MaxNLocator

    class _Compact(Formatter):
        digits = 3

        def set_locs(self, locs):
            # a narrow range far from 0 (v from -0.0201 to -0.0199) needs more than
            # 3 significant digits, or every tick reads "-0.02"
            self.digits = _tick_digits(np.asarray(locs, dtype=float))

        def __call__(self, value, pos=None):
            return _tick_text(value, self.digits)

    axis.set_major_locator(MaxNLocator(nbins))
    axis.set_major_formatter(_Compact())


def _tick_digits(locs: np.ndarray) -> int:
    """Significant digits that tell the ticks ``locs`` apart (at least 3)."""
    locs = np.unique(locs[np.isfinite(locs)])
    if locs.size < 2:
        return 3
    step = np.diff(locs).min()
    return int(np.clip(np.ceil(np.log10(np.abs(locs).max() / step)) + 1, 3, 8))


def _tick_text(value, digits: int = 3) -> str:
    if value == 0 or not np.isfinite(value):
        return "0" if value == 0 else ""
    text = f"{value:.{digits}g}"
    return text.replace("e-0", "e-").replace("e+0", "e")
