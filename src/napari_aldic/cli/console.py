"""What the command line prints: errors, warnings, progress bars, result summaries."""

from __future__ import annotations

import io
import json
import logging
import os
import sys
import time
import traceback
from contextlib import contextmanager, redirect_stdout

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


class _StderrHandler(logging.StreamHandler):
    """Writes to the ``sys.stderr`` of the moment (tests and callers redirect it)."""

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:
        pass


class _Format(logging.Formatter):
    """Warnings as the CLI prints them; info/debug as greppable lines
    ``2026-12-02 01:02:03 napari_aldic INFO frame=1/3 seconds=...``."""

    def format(self, record) -> str:
        if record.levelno >= logging.WARNING:
            return tr("{prog}: warning: {message}").format(prog=PROG,
                                                          message=record.getMessage())
        return (f"{self.formatTime(record, '%Y-%m-%d %H:%M:%S')} {record.name} "
                f"{record.levelname} {record.getMessage()}")


@contextmanager
def logging_for(args):
    """The ``napari_aldic`` logger's output for one command: warnings by
    default, info lines (one per frame) with ``-v``, debug with ``-vv``;
    ``--quiet`` keeps warnings and errors and drops what goes to stdout."""
    log = logging.getLogger("napari_aldic")
    verbose, quiet = getattr(args, "verbose", 0) or 0, getattr(args, "quiet", False)
    handler = _StderrHandler()
    handler.setFormatter(_Format())
    level = logging.DEBUG if verbose >= 2 else logging.INFO if verbose else logging.WARNING
    old = log.level
    log.addHandler(handler)
    log.setLevel(level)
    try:
        if quiet:
            with redirect_stdout(io.StringIO()):
                yield log
        else:
            yield log
    finally:
        close_bar()  # a bar left by an error is erased before the error line
        log.removeHandler(handler)
        log.setLevel(old)


#: the progress display being drawn (cleared before other lines are printed)
_ACTIVE: list = []


class _Bar:
    """A tqdm bar in frames (``total``), moved by the engine's
    :class:`~napari_aldic.engine.ProgressEvent` fractions, so that its time
    left moves within a frame too."""

    def __init__(self, total: int, desc: str):
        from tqdm import tqdm

        self._bar = tqdm(total=total, desc=desc, unit="frame", file=sys.stderr, leave=False,
                         dynamic_ncols=True, bar_format="{desc} {percentage:3.0f}%|{bar}| "
                         "{n:.1f}/{total} frames [{elapsed}<{remaining}] {postfix}")
        self._total = total

    def __call__(self, event) -> None:
        self._bar.n = min(float(event.fraction), 1.0) * self._total
        self._bar.set_postfix_str(str(event)[:40], refresh=False)
        self._bar.refresh()

    def clear(self) -> None:
        self._bar.clear()

    def close(self) -> None:
        self._bar.close()


class _JsonLines:
    """Machine-readable progress for batch jobs: one JSON object per event on
    stderr (``{"progress": 0.25, "stage": ..., "frame": ..., "eta_s": ...}``)."""

    def __init__(self, total: int):
        self._t0, self._total = time.perf_counter(), total

    def __call__(self, event) -> None:
        line = {"progress": round(float(event.fraction), 4), "stage": event.stage,
                "frame": event.frame, "n_frames": event.n_frames or self._total,
                "elapsed_s": round(time.perf_counter() - self._t0, 3),
                "eta_s": None if event.eta_s is None else round(float(event.eta_s), 1)}
        print(json.dumps(line), file=sys.stderr, flush=True)

    def clear(self) -> None:
        pass

    def close(self) -> None:
        pass


def progress_display(mode: str = "auto", n_frames: int = 1, desc: str = ""):
    """A progress callback of engine events, or None: ``"bar"`` (tqdm on
    stderr), ``"json"`` (JSON lines), ``"none"``; ``"auto"`` is a bar when
    stderr is a terminal, else JSON lines for stacks and nothing for pairs."""
    if mode == "auto":
        mode = "bar" if sys.stderr.isatty() else ("json" if n_frames > 1 else "none")
    if mode == "none":
        return None
    shown = _Bar(n_frames, desc) if mode == "bar" else _JsonLines(n_frames)
    _ACTIVE[:] = [shown]
    return shown


def progress_bar(prefix: str):
    """The progress callback of one pair: a bar on an interactive stderr, else None."""
    return progress_display("auto", 1, prefix)


def clear_bar() -> None:
    """Erase a progress bar before printing a line."""
    for shown in _ACTIVE:
        shown.clear()


def close_bar() -> None:
    """Remove the progress display for good (the run is over)."""
    for shown in _ACTIVE:
        shown.close()
    _ACTIVE.clear()


def analysis_seconds(res) -> tuple[float, float]:
    """(analysis, compile) seconds of one result: Numba's first-run
    compilation is not analysis time."""
    t = res.meta.get("timing", {})
    total = float(t.get("total", float("nan")))
    compiling = float(t.get("compile", 0.0))
    return float(t.get("analysis", total - compiling)), compiling


def counts_line(res) -> str:
    """Nodes, valid nodes, time and speed of one result (compile time apart)."""
    total, compiling = analysis_seconds(res)
    pct = 100.0 * res.n_valid / max(len(res), 1)
    line = (tr("{n_res} nodes, {n_valid} valid ({pct:.1f} %), {total:.3f} s "
               "({rate:,.0f} POI/s)").format(
                   n_res=len(res), n_valid=res.n_valid, pct=pct, total=total,
                   rate=len(res) / max(total, 1e-9)))
    if compiling >= 0.05:
        line += tr(" + {seconds:.1f} s compiling kernels (first run only)").format(
            seconds=compiling)
    return line


def kernel_groups(method: str, *extra: str) -> tuple[str, ...]:
    """The kernel groups (``engine.precompile_kernels``) an analysis by ``method`` needs."""
    return ("local", "aldic", *extra) if method == "aldic" else ("local", *extra)


#: the commands that run 2-D analyses (their kernels are compiled ahead)
_ANALYSING = {"run": (), "demo": ("synthetic",), "watch": ("strain",)}


def compile_ahead(argv: list[str]) -> None:
    """Start compiling, in background processes, the kernels the 2-D analysis
    of a ``run``, ``demo`` or ``watch`` command line will need, before the
    commands' modules import and the inputs are read (issue 25: a first run
    ~0.5 s sooner on 2 cores); the command's :func:`precompile` collects them.
    The method is read off ``--method`` (anything else, a settings file's
    choice included, is compiled by :func:`precompile` as before). Nothing
    for help, versions and volumes, nor when the cache holds everything."""
    if not argv or argv[0] not in _ANALYSING or {"-h", "--help", "--volume"} & set(argv):
        return
    import argparse

    pick = argparse.ArgumentParser(add_help=False)
    pick.add_argument("--method")
    try:
        method = pick.parse_known_args(argv[1:])[0].method
    except SystemExit:  # a malformed --method: the real parser says so
        return
    try:
        from ..engine import precompile_kernels

        precompile_kernels(kernel_groups(method or "local", *_ANALYSING[argv[0]]),
                           background=True)
    except Exception as exc:  # noqa: BLE001 - the command compiles them itself
        logging.getLogger("napari_aldic.cli").debug("compiling ahead failed: %s", exc)


def precompile(groups) -> None:
    """Compile the kernels ``groups`` need ahead, in parallel processes, when
    Numba's cache lacks them (a first run); says so, silent otherwise."""
    from ..engine import precompile_kernels

    def started(n_kernels: int, n_procs: int) -> None:
        print("  " + tr("compiling {n_kernels} kernels in {n_procs} processes (first run "
                        "only; later runs load them from Numba's cache) ...").format(
                            n_kernels=n_kernels, n_procs=n_procs), flush=True)

    rep = precompile_kernels(groups, on_start=started)
    if rep.processes:
        print("  " + tr("kernels compiled: {seconds:.1f} s").format(seconds=rep.seconds),
              flush=True)
        logging.getLogger("napari_aldic.cli").info(
            "precompile kernels=%d processes=%d seconds=%.3f failed=%d", len(rep.compiled),
            rep.processes, rep.seconds, len(rep.errors))
    for err in rep.errors:  # they compile at their first call instead
        logging.getLogger("napari_aldic.cli").debug("precompile failed: %s", err)


def log_frame(log, res, label: str, path) -> None:
    """One greppable info line of a finished frame: frame, seconds, compile
    seconds, trusted fraction, nodes, warnings, file (not translated)."""
    total, compiling = analysis_seconds(res)
    flagged = {k: c for k, c in res.reason_counts().items() if k != "converged"}
    log.info("frame=%s seconds=%.3f compile_s=%.3f trusted=%.4f nodes=%d valid=%d "
             "flagged=%s file=%s", label, total, compiling, res.n_valid / max(len(res), 1),
             len(res), res.n_valid,
             ",".join(f"{k.replace(' ', '_')}:{c}" for k, c in flagged.items()) or "none",
             path)


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
