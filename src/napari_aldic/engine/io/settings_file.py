"""Settings files (JSON): :class:`~napari_aldic.engine.Settings` on disk.

:func:`read_settings` / :func:`write_settings` read and write a whole
:class:`Settings`; :func:`save_params`, :func:`load_settings` and
:func:`load_params` are the keyword and dictionary forms kept for callers of
the earlier API. The format and every check live in :mod:`..core.settings`.
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path
from typing import Any

from ..core.files import atomic_write, read_json_file, target_path
from ..core.params import DICParams
from ..core.settings import Settings

__all__ = ["read_settings", "write_settings", "save_params", "load_settings", "load_params"]


def read_settings(path) -> Settings:
    """Read a settings file (or a plain JSON object of DICParams fields).

    Raises
    ------
    FileNotFoundError
        If there is no file at ``path``.
    ValueError
        If the file is a folder, not UTF-8 JSON, not a JSON object, or holds
        an unknown section, key or an invalid value; the message names the
        file and the problem.
    """
    path = Path(os.fspath(path)).expanduser()
    if not os.path.lexists(path):
        raise FileNotFoundError(errno.ENOENT, f"no parameter file at {path} (no such file)",
                                str(path))
    doc = read_json_file(path, "parameter file")
    if not isinstance(doc, dict):
        raise ValueError(f"parameter file {path} must hold a JSON object (a settings "
                         "document or DICParams fields)")
    try:
        return Settings.from_dict(doc)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"parameter file {path}: {exc}") from None


def write_settings(path, settings: Settings) -> Path:
    """Write ``settings`` as readable JSON (``.json`` is appended when the
    name has no suffix); the file is replaced only once complete. Returns the
    path written."""
    if not isinstance(settings, Settings):
        raise TypeError("settings must be a Settings")
    path = target_path(path, (".json",))
    text = json.dumps(settings.to_dict(), indent=2, ensure_ascii=False) + "\n"
    with atomic_write(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
    return path


def save_params(path, params: DICParams, *, units=None, strain=None,
                tracking: dict | None = None) -> Path:
    """Write the analysis settings as readable JSON (see :func:`write_settings`).

    ``units`` is a Units or a dict, ``strain`` a dict of strain settings
    (``True``: the defaults), ``tracking`` a dict of tracking settings; the
    file holds only the sections given. ``napari-aldic run --params FILE``
    and :func:`load_settings` read it.
    """
    if not isinstance(params, DICParams):
        raise TypeError("params must be a DICParams")
    if strain is not None and not isinstance(strain, dict):
        strain = {}
    return write_settings(path, Settings(params, units, strain, tracking))


def load_settings(path) -> dict[str, Any]:
    """The sections of a settings file as a dictionary: ``{"params": DICParams,
    "units": Units or None, "strain": dict or None, "tracking": dict or None}``
    (see :func:`read_settings`, which gives them as one :class:`Settings`)."""
    s = read_settings(path)
    return {"params": s.params, "units": s.units, "strain": s.strain, "tracking": s.tracking}


def load_params(path) -> DICParams:
    """The :class:`DICParams` of a settings file (see :func:`read_settings`)."""
    return read_settings(path).params
