"""The last used parameters, remembered across napari sessions (no Qt here).

A small JSON file in the user's configuration folder (``platformdirs``, e.g.
``~/.config/napari-aldic/last_used.json`` on Linux; the environment variable
``NAPARI_ALDIC_CONFIG_DIR`` names another folder) holds the settings of the
last run: parameters, strain, units, tracking mode and display choices. The
frame range and seed points belong to one stack and are not kept. An
unreadable or outdated file is ignored (the defaults are used).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

__all__ = ["config_dir", "last_used_path", "read_last_used", "write_last_used",
           "LAST_USED_FORMAT", "language_path", "read_language", "write_language"]

LAST_USED_FORMAT = "napari-aldic-last-used"
_VERSION = 1


def config_dir() -> Path:
    """The folder of the plugin's configuration files."""
    env = os.environ.get("NAPARI_ALDIC_CONFIG_DIR")
    if env:
        return Path(env).expanduser()
    from platformdirs import user_config_dir

    return Path(user_config_dir("napari-aldic", appauthor=False))


def last_used_path() -> Path:
    """The file of the last used parameters."""
    return config_dir() / "last_used.json"


def write_last_used(doc: dict) -> Path | None:
    """Store ``doc`` (``{"settings": ..., "init": ..., "display": ...}``); ``None``
    when the folder cannot be written (never an error: this is a convenience)."""
    path = last_used_path()
    body = {"format": LAST_USED_FORMAT, "format_version": _VERSION, **doc}
    try:  # a torn file is only ignored when read (the defaults are used then)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(body, indent=1, ensure_ascii=False), encoding="utf-8")
    except OSError:
        return None
    return path


def read_last_used() -> dict | None:
    """The stored document, or ``None`` (no file, unreadable, another format)."""
    path = last_used_path()
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("format") != LAST_USED_FORMAT or \
            doc.get("format_version") != _VERSION:
        return None
    return doc


def language_path() -> Path:
    """The file of the language chosen in the widget (kept apart from the
    parameters, which every run rewrites)."""
    return config_dir() / "language.json"


def read_language() -> str | None:
    """The language code chosen in the widget, or ``None`` (not chosen, unreadable)."""
    try:
        doc = json.loads(language_path().read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    code = doc.get("language") if isinstance(doc, dict) else None
    return code if isinstance(code, str) and code else None


def write_language(code: str | None) -> Path | None:
    """Remember ``code`` (``None``: follow the system again); ``None`` when the
    folder cannot be written."""
    path = language_path()
    try:
        if code is None:
            path.unlink(missing_ok=True)
            return path
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"language": code}), encoding="utf-8")
    except OSError:
        return None
    return path
