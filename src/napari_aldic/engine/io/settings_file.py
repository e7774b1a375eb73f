"""Parameter/settings files (JSON)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from ..core.files import atomic_write, target_path
from ..core.params import DICParams
from ..core.units import Units
from .columns import software_name
from .runs import SETTINGS_FORMAT, STRAIN_DEFAULTS


# =================================================================== parameters
def save_params(path, params: DICParams, *, units=None, strain=None,
                tracking: dict | None = None) -> Path:
    """Write the complete analysis settings as readable JSON.

    The file holds ``{"format": "napari-aldic-settings", "software": ...,
    "params": {DICParams fields}, "units": {...}, "strain": {...},
    "tracking": {...}}`` (the last three when given).
    ``napari-aldic run --params FILE`` and :func:`load_params` read it.
    """
    if not isinstance(params, DICParams):
        raise TypeError("params must be a DICParams")
    path = target_path(path, (".json",))
    doc: dict[str, Any] = {"format": SETTINGS_FORMAT, "format_version": 1,
                           "software": software_name(), "params": params.to_dict()}
    if units is not None:
        doc["units"] = (units if isinstance(units, Units) else Units.from_dict(units)).to_dict()
    if strain is not None:
        doc["strain"] = {**STRAIN_DEFAULTS, **(strain if isinstance(strain, dict) else {})}
    if tracking is not None:
        doc["tracking"] = dict(tracking)
    text = json.dumps(doc, indent=2, ensure_ascii=False) + "\n"
    with atomic_write(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
    return path


def load_settings(path) -> dict[str, Any]:
    """Read settings written by :func:`save_params` (or a plain JSON object of
    DICParams fields). Returns ``{"params": DICParams, "units": Units or None,
    "strain": dict or None, "tracking": dict or None}``."""
    path = Path(os.fspath(path)).expanduser()
    if not path.exists():
        raise FileNotFoundError(f"no parameter file at {path}")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"parameter file {path} is not valid JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"parameter file {path} must hold a JSON object")
    if doc.get("format") == SETTINGS_FORMAT or "params" in doc and isinstance(doc["params"],
                                                                             dict):
        known = {"format", "format_version", "software", "params", "units", "strain",
                 "tracking"}
        unknown = sorted(set(doc) - known)
        if unknown:
            raise ValueError(f"parameter file {path}: unknown section(s) {unknown}; valid "
                             f"sections are {sorted(known)}")
        try:
            params = DICParams.from_dict(doc.get("params") or {})
        except (TypeError, ValueError) as exc:
            raise ValueError(f"parameter file {path}: {exc}") from None
        units = Units.from_dict(doc["units"]) if doc.get("units") else None
        return {"params": params, "units": units, "strain": doc.get("strain"),
                "tracking": doc.get("tracking")}
    try:
        params = DICParams.from_dict(doc)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"parameter file {path}: {exc}") from None
    return {"params": params, "units": None, "strain": None, "tracking": None}


def load_params(path) -> DICParams:
    """The :class:`DICParams` of a settings file (see :func:`load_settings`)."""
    return load_settings(path)["params"]


