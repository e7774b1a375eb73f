"""``main``: parse the command line, run the command, turn errors into one line."""

from __future__ import annotations

import logging
import signal
import sys
import warnings

from ..i18n import set_language, tr
from .advise import advise_command, noise_floor_command
from .console import (
    DEBUG_ENV,
    PROG,
    CLIError,
    debugging,
    logging_for,
    print_error,
    show_traceback,
    show_warning,
    silence_stdout,
)
from .demo import demo_command
from .export import export_command
from .params import params_command
from .parser import build_parser
from .probe import probe_command
from .run import run_command
from .sem import sem_calibrate_command, sem_drift_command
from .watch import watch_command

#: command name -> function(args) returning the exit code (None: 0)
COMMANDS = {"demo": demo_command, "run": run_command, "export": export_command,
            "params": params_command, "probe": probe_command, "advise": advise_command,
            "noise-floor": noise_floor_command,
            "sem-calibrate": sem_calibrate_command, "sem-drift": sem_drift_command,
            "watch": watch_command}


def main(argv: list[str] | None = None, restore_sigint=None) -> int:
    """Entry point of the ``napari-aldic`` console script; returns the exit code.

    Every error ends the command with one line, ``napari-aldic: error: ...``,
    and exit code 2 (130 when interrupted); with the environment variable
    ``NAPARI_ALDIC_DEBUG=1`` the traceback is printed above that line.
    ``restore_sigint`` is the SIGINT handler to put back once the command
    starts (:func:`napari_aldic.cli.main` quits at once on Ctrl-C until then).
    """
    set_language(None)  # the environment's language, read now (docs/languages.md)
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, usage errors
        return int(exc.code or 0)
    tiff_log = logging.getLogger("tifffile")
    if not debugging() and not any(isinstance(h, logging.NullHandler)
                                   for h in tiff_log.handlers):
        tiff_log.addHandler(logging.NullHandler())  # the engine reports damage in one line
    with warnings.catch_warnings():
        warnings.showwarning = show_warning
        try:
            if restore_sigint is not None:  # from now on Ctrl-C raises KeyboardInterrupt
                signal.signal(signal.SIGINT, restore_sigint)
            with logging_for(args):
                return COMMANDS[args.command](args) or 0
        except BrokenPipeError:  # stdout piped into a program that stopped reading
            silence_stdout()
            return 1
        except (CLIError, ValueError, TypeError, OSError, NotImplementedError) as exc:
            show_traceback()
            missing = isinstance(exc, FileNotFoundError) and exc.filename
            print_error(tr("no such file: {filename}").format(filename=exc.filename)
                        if missing else str(exc) or repr(exc))
            return 2
        except MemoryError:
            show_traceback()
            print_error(tr("out of memory: the input is too large for this computer (a "
                           "smaller region, a larger step or fewer frames at once need "
                           "less)"))
            return 2
        except Exception as exc:  # a bug or an input nobody foresaw: still one line
            show_traceback()
            print_error(tr("unexpected {name__}: {exc} (set {debug_env}=1 to see where it "
                           "happened, and please report it)").format(
                               name__=type(exc).__name__, exc=exc, debug_env=DEBUG_ENV))
            return 2
        except KeyboardInterrupt:
            print(tr("{prog}: interrupted (results already written are kept)").format(prog=PROG),
                  file=sys.stderr)
            return 130
