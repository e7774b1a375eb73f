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
import math
import os
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from ..engine import InputFileError, Settings
from ..engine.io import available_memory, file_sha256, read_json_file
from ..i18n import tr

__all__ = ["PROJECT_FORMAT", "PROBE_KEY", "ROLES", "is_probe_layer", "image_record",
           "layer_record", "file_identity", "relative_path",
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
    """The array of :func:`encode_array` (``ValueError`` when it does not fit,
    or would need more memory than is available: checked before decompressing)."""
    try:
        dtype, shape = np.dtype(d["dtype"]), [int(n) for n in d["shape"]]
        if dtype.hasobject or any(n < 0 for n in shape):
            raise ValueError(f"dtype {dtype}, shape {shape}")
        need = math.prod(shape) * dtype.itemsize
        avail = available_memory()
        if avail is not None and need > avail:
            raise MemoryError(need, avail)
        z = zlib.decompressobj()
        raw = z.decompress(base64.b64decode(d["zlib_base64"], validate=True), need + 1)
        return np.frombuffer(raw, dtype).reshape(shape).copy()
    except MemoryError as exc:
        need, avail = exc.args if len(exc.args) == 2 else (0, 0)
        raise ValueError(tr("a labels layer of the project would need {gib:.1f} GiB, more "
                            "than the memory available ({avail:.1f} GiB)").format(
                                gib=need / 2**30, avail=avail / 2**30)) from None
    except (KeyError, TypeError, ValueError, zlib.error, OverflowError) as exc:
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
    # absolute now (a relative name means the folder napari was started in);
    # write_project stores it relative to the project file
    if isinstance(path, (list, tuple)):
        path = [os.path.abspath(os.fspath(p)) for p in path]
    elif path:
        path = os.path.abspath(os.fspath(path))
    data = layer.data[0] if getattr(layer, "multiscale", False) else layer.data
    return {"name": layer.name, "path": path or None,
            "sample": list(sample) if sample else None, "shape": list(np.shape(data)),
            "files": _identities(path) if path else None,
            "scale": [float(s) for s in layer.scale],
            "translate": [float(t) for t in layer.translate]}


def _identities(path) -> list[dict] | None:
    """Size and content digest of the image file(s) (None for a folder)."""
    paths = path if isinstance(path, list) else [path]
    if not all(os.path.isfile(p) for p in paths):
        return None
    return [file_identity(p, "image file") for p in paths]


def file_identity(path, what: str) -> dict:
    """Size and SHA-256 of a file a project refers to (``what`` names it in errors)."""
    return {"size": os.path.getsize(path), "sha256": file_sha256(path, what)}


def relative_path(path, folder: Path):
    """``path`` (or each of a list) relative to ``folder`` where it can be."""
    if isinstance(path, list):
        return [relative_path(p, folder) for p in path]
    try:
        return os.path.relpath(path, folder)
    except ValueError:  # another drive (Windows): keep it absolute
        return os.fspath(path)


def _resolved(path, folder: Path):
    """``path`` (or each of a list) resolved against the project's ``folder``."""
    if isinstance(path, list):
        return [_resolved(p, folder) for p in path]
    return str(folder / Path(os.fspath(path)).expanduser())


def check_image_files(image: dict) -> None:
    """Refuse image files that are not those the project was saved with
    (``ValueError`` naming the file and what changed): a replaced image would
    silently put the layers on other pixels."""
    files, path = image.get("files"), image.get("path")
    paths = path if isinstance(path, list) else [path]
    if not isinstance(files, list) or len(files) != len(paths):
        return  # a project of an earlier version, or a folder of images
    for p, rec in zip(paths, files):
        if not os.path.exists(p) or not isinstance(rec, dict):
            continue  # reported when the image is opened
        size = os.path.getsize(p)
        if size != rec.get("size"):
            detail = f"size {rec.get('size')} -> {size} bytes"
        else:
            digest = file_sha256(p, "image file")
            if digest == rec.get("sha256"):
                continue
            detail = f"sha256 {str(rec.get('sha256'))[:12]} -> {digest[:12]}"
        raise ValueError(image_changed(p, detail))


def image_changed(path, detail: str) -> str:
    return tr("the image {path} of the project has changed since the project was saved "
              "({detail}); put the original back, or open the new image and save the "
              "project again").format(path=path, detail=detail)


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


def _numbers(value, n: int | None = None) -> bool:
    """A list of finite numbers (of length ``n``)."""
    return isinstance(value, list) and (n is None or len(value) == n) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        for v in value)


def _bad_key(rec: dict) -> str | None:
    """The first entry of a stored layer that is missing or of the wrong kind
    (a hand-edited or damaged project), else None."""
    if not isinstance(rec.get("name"), str):
        return "name"
    for key in ("scale", "translate"):
        if not _numbers(rec.get(key)) or not 2 <= len(rec[key]) <= 5:
            return key
    ndim, data = len(rec["scale"]), rec.get("data")
    if len(rec["translate"]) != ndim:
        return "translate"
    if rec["type"] == "shapes":
        if not isinstance(data, list) or not all(
                isinstance(v, list) and v and all(_numbers(p, ndim) for p in v) for v in data):
            return "data"
        if not (isinstance(rec.get("shape_type"), list) and len(rec["shape_type"]) == len(data)
                and all(isinstance(t, str) for t in rec["shape_type"])):
            return "shape_type"
        if not _numbers(rec.get("edge_width"), len(data)):
            return "edge_width"
    elif rec["type"] == "points":
        if not isinstance(data, list) or not all(_numbers(p, ndim) for p in data):
            return "data"
        if not _numbers([rec.get("size", 6.0)]):
            return "size"
    elif not (isinstance(data, dict) and isinstance(data.get("dtype"), str)
              and _numbers(data.get("shape"), ndim)
              and isinstance(data.get("zlib_base64"), str)):
        return "data"
    return None


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
    path = image.get("path")
    if path and not (isinstance(path, str) or (isinstance(path, list) and all(
            isinstance(p, str) for p in path))):
        raise ValueError(tr("layer {number} of the project is damaged: its '{key}' entry is "
                            "missing or invalid").format(number="-", key="image.path"))
    for key in ("scale", "translate"):
        if key in image and not _numbers(image[key]):
            raise ValueError(tr("layer {number} of the project is damaged: its '{key}' entry "
                                "is missing or invalid").format(number="-", key=f"image.{key}"))
    layers = doc.get("layers", [])
    if not isinstance(layers, list):
        raise ValueError(tr("layer {number} of the project is damaged: its '{key}' entry is "
                            "missing or invalid").format(number="-", key="layers"))
    for i, rec in enumerate(layers):
        if not isinstance(rec, dict) or rec.get("role") not in ROLES:
            raise ValueError(tr("a stored layer has no valid role (one of {join})").format(
                                    join=', '.join(ROLES)))
        allowed = _KINDS[rec["role"]]
        if rec.get("type") not in (allowed if isinstance(allowed, tuple) else (allowed,)):
            raise ValueError(tr("layer '{get}': a {get2} layer cannot be the {role}").format(
                                    get=rec.get('name'), get2=rec.get('type'), role=rec['role']))
        bad = _bad_key(rec)
        if bad:
            raise ValueError(tr("layer {number} of the project is damaged: its '{key}' entry "
                                "is missing or invalid").format(number=i + 1, key=bad))
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
        doc = read_json_file(path, "project file")
    except InputFileError as exc:
        if exc.kind == "encoding":
            raise ValueError(tr("{path} is not a text (UTF-8) file").format(path=path)) from None
        if exc.kind == "json":
            raise ValueError(tr("{path} is not valid JSON ({exc})").format(
                path=path, exc=exc.problem.removeprefix("is not valid JSON (")[:-1])) from None
        raise
    try:
        doc = _check(doc)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    image = doc["image"]
    if image.get("path"):  # stored relative to the project file
        image["path"] = _resolved(image["path"], path.absolute().parent)
        check_image_files(image)
    return doc


def write_project(path, doc: dict) -> Path:
    """Write a project document (``.json`` appended when the name has no suffix)."""
    path = Path(os.fspath(path)).expanduser()
    if not path.suffix:
        path = path.with_suffix(".json")
    body = {"format": PROJECT_FORMAT, "format_version": PROJECT_VERSION, **doc}
    image = body.get("image")
    if isinstance(image, dict) and image.get("path"):
        body["image"] = {**image, "path": relative_path(image["path"], path.absolute().parent)}
    _check(json.loads(json.dumps(body)))  # what is written reads back
    path.write_text(json.dumps(body, indent=1, ensure_ascii=False), encoding="utf-8")
    return path
