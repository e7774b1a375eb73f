"""Settings files (JSON): :class:`~napari_aldic.engine.Settings` on disk.

:func:`read_settings` / :func:`write_settings` read and write a whole
:class:`Settings` (the keyword forms of 0.1, ``save_params``, ``load_settings``
and ``load_params``, are retired). The format and every check live in
:mod:`..core.settings`.
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

from ..core.files import atomic_write, read_json_file, target_path
from ..core.settings import Settings

__all__ = ["read_settings", "write_settings"]


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
