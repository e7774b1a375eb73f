"""What the command line prints: errors, warnings, progress bars, result summaries."""

from __future__ import annotations

import os
import sys
import time
import traceback

import numpy as np

from ..i18n import tr

PROG = "napari-aldic"
#: environment variable that adds the traceback to an error line
DEBUG_ENV = "NAPARI_ALDIC_DEBUG"


class CLIError(Exception):
    """A user-facing error: printed as one line, no traceback."""


def one_line(message: str) -> str:
    """``message`` with its lines joined into one."""
    return " ".join(line.strip() for line in message.splitlines() if line.strip())


def print_error(message: str) -> None:
    print(tr("{prog}: error: {message}").format(prog=PROG, message=one_line(message)),
          file=sys.stderr)


def debugging() -> bool:
    """Whether :data:`DEBUG_ENV` is set (to anything but empty or 0)."""
    return os.environ.get(DEBUG_ENV, "") not in ("", "0")


def show_traceback() -> None:
    """Print the traceback of the error being handled when :func:`debugging`."""
    if debugging():
        traceback.print_exc(file=sys.stderr)


def show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """``warnings.showwarning`` of the CLI: one line, no source location."""
    print(tr("{prog}: warning: {message}").format(prog=PROG, message=message), file=sys.stderr)


def silence_stdout() -> None:
    """Send further output to the null device (stdout's reader has gone)."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass


def progress_bar(prefix: str):
    """A progress callback drawing a bar on an interactive stderr, else None."""
    if not sys.stderr.isatty():
        return None

    def report(frac, msg: str | None = None) -> None:
        if msg is None:  # a ProgressEvent of correlate (correlate_tiled gives two values)
            frac, msg = frac.fraction, str(frac)
        n = int(round(30 * frac))
        end = "\n" if frac >= 1 else ""
        print(f"\r{prefix} [{'#' * n}{'.' * (30 - n)}] {frac:4.0%} {msg:<40.40}", end=end,
              file=sys.stderr, flush=True)

    return report


def sequence_progress(n_frames: int):
    """Progress bar over frames with the estimated time left (interactive stderr)."""
    if not sys.stderr.isatty():
        return None
    t0 = time.perf_counter()

    def report(event) -> None:
        frac, msg = event.fraction, str(event)
        el = time.perf_counter() - t0
        left = el * (1 - frac) / frac if frac > 0 else float("nan")
        eta = "--:--" if not np.isfinite(left) else f"{int(left) // 60:02d}:{int(left) % 60:02d}"
        done = int(round(frac * n_frames))
        bar = int(round(30 * frac))
        line = tr("{done}/{n_frames} frames, {el:5.1f} s, {eta} left").format(
            done=done, n_frames=n_frames, el=el, eta=eta)
        print(f"\r  [{'#' * bar}{'.' * (30 - bar)}] {line}  {msg:<28.28}", end="",
              file=sys.stderr, flush=True)

    return report


def clear_bar() -> None:
    """Erase a progress bar before printing a line."""
    if sys.stderr.isatty():
        print("\r" + " " * 100 + "\r", end="", file=sys.stderr, flush=True)


def counts_line(res) -> str:
    """Nodes, valid nodes, time and speed of one result."""
    total = float(res.meta.get("timing", {}).get("total", float("nan")))
    pct = 100.0 * res.n_valid / max(len(res), 1)
    return (tr("{n_res} nodes, {n_valid} valid ({pct:.1f} %), {total:.3f} s "
               "({rate:,.0f} POI/s)").format(
                   n_res=len(res), n_valid=res.n_valid, pct=pct, total=total,
                   rate=len(res) / max(total, 1e-9)))


def frame_summary(res) -> list[str]:
    """Lines describing one result: counts, time, displacement range, flags."""
    lines = [counts_line(res)]
    v = res.valid
    if v.any():
        lines.append(tr("u mean {mean:+.4f} px [{min:+.3f}, {max:+.3f}]; v mean "
                        "{mean2:+.4f} px [{min2:+.3f}, {max2:+.3f}]; median ZNCC "
                        "{median:.4f}").format(
                            mean=res.u[v].mean(), min=res.u[v].min(), max=res.u[v].max(),
                            mean2=res.v[v].mean(), min2=res.v[v].min(), max2=res.v[v].max(),
                            median=np.median(res.zncc[v])))
    if res.aldic_summary():
        lines.append(res.aldic_summary())
    flagged = {k: c for k, c in res.reason_counts().items() if k != "converged"}
    if flagged:
        lines.append(tr("flagged:") + " " + ", ".join(f"{k}: {c}" for k, c in flagged.items()))
    return lines
