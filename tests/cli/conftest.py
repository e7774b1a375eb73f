"""Fixtures of the command-line tests."""

from __future__ import annotations

import contextlib
import io

import pytest

from napari_aldic.cli import main


def _main_in_process(argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope="session")
def run_cli():
    """``run_cli(argv)`` runs ``napari-aldic ARGV`` in-process and returns
    ``(exit code, stdout, stderr)``; arguments may be paths or numbers."""
    return _main_in_process
