"""``napari-aldic params``: write a settings file."""

from __future__ import annotations

from ..engine.io import write_settings
from ..i18n import tr
from .console import PROG
from .settings import settings_from_args


def params_command(args) -> None:
    """``napari-aldic params OUT.json``: the defaults or ``--params FILE`` with
    the options applied (parameters, units, strain, tracking reference)."""
    settings = settings_from_args(args, args.params)
    if args.reference is not None:
        settings = settings.replace(tracking={**(settings.tracking or {}),
                                              "reference": args.reference})
    path = write_settings(args.output, settings)
    print(tr("wrote parameters to {resolve}").format(resolve=path.resolve()))
    print(tr("use them with: {prog} run INPUT ... --params {path}").format(prog=PROG, path=path))
