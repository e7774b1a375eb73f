"""Command line interface: ``napari-aldic demo``, ``run``, ``export`` and ``params``.

``demo`` renders a synthetic speckle pair with exact truth, analyses it and
reports the error; ``run`` analyses an image pair, a multi-page TIFF stack or a
folder of images (frame 0 is the reference; every other frame is correlated
against it) and writes one ``.npz`` result per frame; ``export`` turns results
(a ``.npz``, several, or a run folder) into MATLAB, CSV, VTK, DaVis text,
PNG/GIF/MP4 images and a PDF report; ``params`` writes a settings file.

Errors in the input (missing or unreadable files, bad parameters, images the
engine rejects) print ``napari-aldic: error: <message>`` and exit with code 2.

Modules: :mod:`.parser` (the argument parser), :mod:`.app` (``main``), one
module per command (:mod:`.demo`, :mod:`.run`, :mod:`.params`, :mod:`.export`),
:mod:`.settings` (settings file + options) and :mod:`.console` (output). The
CLI uses the engine's public API only.

This module imports nothing heavy: :func:`main` first makes Ctrl-C during the
imports of NumPy, SciPy and the engine (the first seconds) end the process
with one line and exit code 130, as Ctrl-C during a command does.
"""

import atexit
import os
import signal
import sys
import threading

__all__ = ["main", "console_main", "build_parser"]

_INTERRUPTED = "{prog}: interrupted (results already written are kept)"


def _quit_now(signum, frame) -> None:  # pragma: no cover - runs in a child process
    """SIGINT before a command has started: nothing is written yet, so leave
    at once (a KeyboardInterrupt raised inside an import prints a traceback)."""
    text = _INTERRUPTED
    i18n = sys.modules.get("napari_aldic.i18n")
    try:
        text = i18n.tr(text) if i18n is not None and hasattr(i18n, "tr") else text
    except Exception:
        pass
    try:
        os.write(2, (text.format(prog="napari-aldic") + "\n").encode("utf-8", "replace"))
    finally:
        os._exit(130)


def main(argv=None) -> int:
    """Entry point of the ``napari-aldic`` console script (see :func:`.app.main`)."""
    previous = None
    if threading.current_thread() is threading.main_thread() and \
            signal.getsignal(signal.SIGINT) not in (signal.SIG_IGN, None):
        previous = signal.signal(signal.SIGINT, _quit_now)
    try:
        from .console import compile_ahead

        # a first run: the kernels compile while the commands' modules import
        compile_ahead(sys.argv[1:] if argv is None else list(argv))
        from .app import main as run
    except BaseException:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
        raise
    try:
        return run(argv, restore_sigint=previous)
    finally:
        if previous is not None:  # the command is over: Ctrl-C while Python shuts down
            signal.signal(signal.SIGINT, _quit_now)


def console_main() -> None:  # pragma: no cover - runs as its own process
    """The ``napari-aldic`` console script and ``python -m napari_aldic.cli``:
    :func:`main`, then the exit handlers, and the process ends with its code.
    Python's own teardown of NumPy, SciPy and numba is skipped: it takes a
    while, and Ctrl-C during it would kill the process without a word."""
    code = main()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    os._exit(code if isinstance(code, int) else 1)


def __getattr__(name: str):
    if name == "build_parser":
        from .parser import build_parser

        return build_parser
    raise AttributeError(f"module 'napari_aldic.cli' has no attribute {name!r}")
