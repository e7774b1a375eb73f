"""Project files: a whole analysis set-up in one JSON file (no Qt here).

A project holds what a user set up: the image (its file or folder, or the
sample it came from), the Shapes/Labels/Points layers chosen as ROI, holes,
ROI labels, refine region and seeds, the probe layers (:func:`is_probe_layer`:
Points/Shapes layers marked with the metadata key :data:`PROBE_KEY` or named
like "probes"), the settings (a
:class:`~napari_aldic.engine.Settings` document: parameters, units, strain,
tracking) and the display choices. Reopening it opens the image, adds the
layers, chooses them again and sets every control.

Layer data are stored in the layer's own data coordinates with its scale and
offset (Labels compressed: zlib + base64), so they land where they were.
"""

from __future__ import annotations

import base64
import json
import os
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from ..engine import Settings
from ..i18n import tr

__all__ = ["PROJECT_FORMAT", "PROBE_KEY", "ROLES", "is_probe_layer", "image_record",
           "layer_record",
           "layer_data", "read_project", "write_project", "encode_array", "decode_array"]

PROJECT_FORMAT = "napari-aldic-project"
PROJECT_VERSION = 1
#: metadata key that marks a Points/Shapes layer as a probe (saved with the project)
PROBE_KEY = "napari_aldic_probe"
#: the role of each stored layer: a choice of the Inputs panel, or a probe
ROLES = ("roi_add", "roi_subtract", "roi_labels", "brush", "seeds", "probe")
_KINDS = {"roi_add": "shapes", "roi_subtract": "shapes", "roi_labels": "labels",
          "brush": "labels", "seeds": "points", "probe": ("points", "shapes")}


def is_probe_layer(layer) -> bool:
    """A Points/Shapes layer that measures (a probe): marked with :data:`PROBE_KEY`
    in its metadata, or named like one (the probe dock's "probes", "probe points")."""
    return layer.__class__.__name__ in ("Points", "Shapes") and (
        PROBE_KEY in (getattr(layer, "metadata", None) or {})
        or "probe" in str(layer.name).lower())


def encode_array(a: np.ndarray) -> dict:
    """A compact JSON form of an integer array (labels): zlib + base64."""
    a = np.ascontiguousarray(a)
    return {"dtype": a.dtype.str, "shape": list(a.shape),
            "zlib_base64": base64.b64encode(zlib.compress(a.tobytes(), 6)).decode("ascii")}


def decode_array(d: dict) -> np.ndarray:
    """The array of :func:`encode_array` (``ValueError`` when it does not fit)."""
    try:
        raw = zlib.decompress(base64.b64decode(d["zlib_base64"]))
        return np.frombuffer(raw, np.dtype(d["dtype"])).reshape(d["shape"]).copy()
    except (KeyError, TypeError, ValueError, zlib.error) as exc:
        raise ValueError(tr("a labels layer of the project cannot be read ({exc})").format(
                                exc=exc)) from None


def _json_safe(value) -> Any:
    """``value`` if JSON can hold it, else its text."""
    try:
        json.dumps(value)
        return value
    except (TypeError, ValueError):
        return str(value)


def image_record(layer) -> dict:
    """Where the image comes from: its file(s) or its sample, and its placement.

    Raises ``ValueError`` for an image that came from neither (e.g. made in the
    console): a project refers to images, it does not hold them."""
    meta = layer.metadata or {}
    source = getattr(layer, "source", None)
    path = getattr(source, "path", None) or meta.get("source")
    sample = getattr(source, "sample", None)
    if not path and not sample:
        raise ValueError(tr("the image layer '{layer_name}' was not opened from a file or "
                            "a sample, so a project cannot refer to it: save it first "
                            "(File > Save Selected Layers... as .tif), open that file, "
                            "then save the project").format(
                                layer_name=layer.name))
    if isinstance(path, (list, tuple)):
        path = [str(p) for p in path]
    elif path:
        path = str(path)
    return {"name": layer.name, "path": path or None,
            "sample": list(sample) if sample else None,
            "scale": [float(s) for s in layer.scale],
            "translate": [float(t) for t in layer.translate]}


def layer_record(layer, role: str) -> dict:
    """A Shapes, Labels or Points layer as a JSON object (``role``: see :data:`ROLES`)."""
    kind = layer.__class__.__name__.lower()
    rec: dict[str, Any] = {"role": role, "type": kind, "name": layer.name,
                           "scale": [float(s) for s in layer.scale],
                           "translate": [float(t) for t in layer.translate]}
    if kind == "shapes":
        rec["data"] = [np.asarray(v, float).tolist() for v in layer.data]
        rec["shape_type"] = list(layer.shape_type)
        rec["edge_width"] = [float(w) for w in np.broadcast_to(
            np.asarray(layer.edge_width, float), (len(layer.data),))]
    elif kind == "points":
        rec["data"] = np.asarray(layer.data, float).tolist()
        size = np.asarray(layer.size, float)
        rec["size"] = float(np.median(size)) if size.size else 6.0
    elif kind == "labels":
        data = layer.data[0] if getattr(layer, "multiscale", False) else layer.data
        rec["data"] = encode_array(np.asarray(data))
    else:
        raise ValueError(tr("layer '{layer_name}' is a {kind} layer; a project stores "
                            "Shapes, Labels and Points layers").format(
                                layer_name=layer.name, kind=kind))
    meta = (layer.metadata or {}).get(PROBE_KEY)
    if meta is not None:
        rec["probe"] = _json_safe(meta)
    return rec


#: how each role's layer looks when it is added again
_STYLE = {"roi_add": {"face_color": "transparent", "edge_color": "yellow"},
          "roi_subtract": {"face_color": "transparent", "edge_color": "red"},
          "probe": {"face_color": "transparent", "edge_color": "cyan"},
          "seeds": {"face_color": "cyan"}}


def layer_data(rec: dict) -> tuple:
    """The layer-data tuple ``(data, kwargs, kind)`` of a stored layer."""
    kind, role = rec["type"], rec["role"]
    kw: dict[str, Any] = {"name": rec["name"], "scale": rec["scale"],
                          "translate": rec["translate"]}
    if "probe" in rec:
        kw["metadata"] = {PROBE_KEY: rec["probe"]}
    if kind == "shapes":
        data = [np.asarray(v, float) for v in rec["data"]]
        style = _STYLE.get(role, {})
        if kw.get("metadata") is None and role == "probe":
            kw["metadata"] = {PROBE_KEY: True}
        kw.update(shape_type=rec["shape_type"], edge_width=rec["edge_width"],
                  **(style if data else {}))
        return data, kw, "shapes"
    if kind == "points":
        data = np.asarray(rec["data"], float).reshape(-1, len(rec["scale"]))
        kw.update(size=rec.get("size", 6.0), **(_STYLE.get(role, {}) if role == "seeds"
                                                else {}))
        return data, kw, "points"
    if kind == "labels":
        kw["opacity"] = 0.4
        return decode_array(rec["data"]), kw, "labels"
    raise ValueError(tr("unknown layer type {kind!r} in the project").format(kind=kind))


def _check(doc) -> dict:
    """The project document, checked (``ValueError`` naming the problem)."""
    if not isinstance(doc, dict) or doc.get("format") != PROJECT_FORMAT:
        raise ValueError(tr("not a napari-aldic project file (no \"format\": "
                            "\"{project_format}\")").format(
                                project_format=PROJECT_FORMAT))
    if doc.get("format_version") != PROJECT_VERSION:
        raise ValueError(tr("project format version {get!r} is not {project_version}; use "
                            "a newer napari-aldic").format(
                                get=doc.get('format_version'), project_version=PROJECT_VERSION))
    image = doc.get("image")
    if not isinstance(image, dict) or not (image.get("path") or image.get("sample")):
        raise ValueError(tr("the project names no image (an 'image' with a path or a "
                            "sample)"))
    for rec in doc.get("layers", []):
        if not isinstance(rec, dict) or rec.get("role") not in ROLES:
            raise ValueError(tr("a stored layer has no valid role (one of {join})").format(
                                    join=', '.join(ROLES)))
        allowed = _KINDS[rec["role"]]
        if rec.get("type") not in (allowed if isinstance(allowed, tuple) else (allowed,)):
            raise ValueError(tr("layer '{get}': a {get2} layer cannot be the {role}").format(
                                    get=rec.get('name'), get2=rec.get('type'), role=rec['role']))
        layer_data(rec)  # the data decode
    Settings.from_dict(doc.get("settings") or {})
    if doc.get("init") not in (None, "fft", "seeds"):
        raise ValueError(tr("initial guess {get!r} must be 'fft' or 'seeds'").format(
                                get=doc.get('init')))
    if not isinstance(doc.get("display", {}), dict):
        raise ValueError(tr("the 'display' section must be a JSON object"))
    return doc


def read_project(path) -> dict:
    """Read and check a project file (``ValueError``/``OSError`` naming the file)."""
    path = Path(os.fspath(path)).expanduser()
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise ValueError(tr("{path} is not a text (UTF-8) file").format(path=path)) from None
    except json.JSONDecodeError as exc:
        raise ValueError(tr("{path} is not valid JSON ({exc})").format(path=path,
                                                                         exc=exc)) from None
    try:
        return _check(doc)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def write_project(path, doc: dict) -> Path:
    """Write a project document (``.json`` appended when the name has no suffix)."""
    path = Path(os.fspath(path)).expanduser()
    if not path.suffix:
        path = path.with_suffix(".json")
    body = {"format": PROJECT_FORMAT, "format_version": PROJECT_VERSION, **doc}
    _check(json.loads(json.dumps(body)))  # what is written reads back
    path.write_text(json.dumps(body, indent=1, ensure_ascii=False), encoding="utf-8")
    return path
