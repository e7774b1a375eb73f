"""The results and the load file of a project (no Qt here; issue 24, trap 16).

Saving a project with results writes them beside it, as the engine's result files
(``<project>_results/frame_#####.npz``, one per computed frame, the reference frame
included), and the project refers to that folder relative to itself, with the size
and SHA-256 of each file. Opening the project reads them back after checking each
file (a missing or changed file is named, and the analysis is not restored: run it
again), so the analysis is there again without running it.

The probe dock's testing-machine CSV (and its synchronisation) is kept in the same
way: the path relative to the project, its size and digest, and the options.
"""

from __future__ import annotations

import os
from pathlib import Path

from .._analysis import Analysis, StrainSettings
from ..engine import compute_strain, load_result
from ..engine.io import file_sha256
from ..i18n import tr
from .project import file_identity, relative_path

__all__ = ["LOAD_KEY", "LOAD_OPTIONS", "results_record", "restore_results", "load_record",
           "restore_load", "keep_load", "kept_load"]

#: the probe dock's load file and options, in the metadata of its probe Shapes layer
LOAD_KEY = "napari_aldic_load"
LOAD_OPTIONS = ("area_mm2", "sync", "fps", "offset")


def _changed(path: Path, rec: dict) -> str | None:
    """Why the file at ``path`` is not the one recorded (``None``: it is)."""
    if not path.is_file():
        return tr("{path} is not there (moved or deleted?)").format(path=path)
    if path.stat().st_size != rec.get("size") or file_sha256(path, "file") != rec.get("sha256"):
        return tr("{path} has changed since the project was saved").format(path=path)
    return None


# ------------------------------------------------------------------ results
def results_record(analysis: Analysis, project: Path, units) -> dict:
    """Write ``analysis`` beside the project file ``project`` and return the
    project's ``"results"`` entry (paths relative to the project's folder)."""
    project = Path(project).absolute()
    folder = project.with_name(project.stem + "_results")
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("frame_*.npz"):  # an earlier save's frames
        old.unlink()
    files = []
    for k, r in zip(analysis.frames, analysis.results):
        if r is None:
            continue
        if units is not None:
            r.meta["units"] = units.to_dict()  # the result file says its units too
        written = Path(r.save(folder / f"frame_{int(k):05d}.npz"))
        files.append({"frame": int(k), "name": written.name,
                      **file_identity(written, "result file")})
    return {"folder": relative_path(folder, project.parent), "files": files,
            "frames": [int(k) for k in analysis.frames], "n_frames": analysis.n_frames,
            "reference": analysis.reference, "strain": analysis.strain.to_dict(),
            "cancelled": bool(analysis.cancelled), "seconds": float(analysis.seconds)}


def restore_results(rec: dict, project: Path, source: str) -> Analysis:
    """The analysis of a project's ``"results"`` entry (``ValueError`` naming a
    missing or changed file, or a damaged entry); ``source``: the image's name."""
    try:
        folder = Path(os.path.normpath(Path(project).absolute().parent / os.fspath(rec["folder"])))
        frames = [int(k) for k in rec["frames"]]
        files = {int(f["frame"]): f for f in rec["files"]}
        strain = StrainSettings(**rec.get("strain", {}))
        n_frames = None if rec.get("n_frames") is None else int(rec["n_frames"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(tr("the project's results entry is damaged ({exc})").format(
            exc=exc)) from None
    results, strains = [], []
    for k in frames:
        if k not in files:
            results.append(None)
            strains.append(None)
            continue
        path = folder / str(files[k]["name"])
        why = _changed(path, files[k])
        if why:
            raise ValueError(why)
        r = load_result(path)
        results.append(r)
        strains.append(compute_strain(r, window=strain.window, method=strain.method,
                                      measure=strain.measure))
    done = [r for r in results if r is not None]
    if not done:
        raise ValueError(tr("the project's results entry lists no result file"))
    return Analysis(results=results, strains=strains, frames=frames, n_frames=n_frames,
                    params=done[-1].params,
                    reference=str(rec.get("reference", "accumulative")), strain=strain,
                    cancelled=bool(rec.get("cancelled", False)),
                    seconds=float(rec.get("seconds", 0.0)), source=source)


# ------------------------------------------------------------------ load file
def load_record(options: dict, project: Path) -> dict | None:
    """The project's ``"load"`` entry of the probe dock's load ``options``
    (``{"path", "area_mm2", "sync", "fps", "offset"}``), or None without a file."""
    path = options.get("path")
    if not path or not Path(path).is_file():
        return None
    path = Path(path).absolute()
    rec = {"path": relative_path(path, Path(project).absolute().parent),
           **file_identity(path, "load file")}
    rec.update({k: options[k] for k in LOAD_OPTIONS if options.get(k) is not None})
    return rec


def restore_load(rec: dict, project: Path) -> dict:
    """The load options of a project's ``"load"`` entry, the path resolved and the
    file checked (``ValueError`` naming a missing or changed file)."""
    try:
        path = Path(os.path.normpath(Path(project).absolute().parent / os.fspath(rec["path"])))
    except (KeyError, TypeError) as exc:
        raise ValueError(tr("the project's load entry is damaged ({exc})").format(
            exc=exc)) from None
    why = _changed(path, rec)
    if why:
        raise ValueError(why)
    return {"path": str(path), **{k: rec[k] for k in LOAD_OPTIONS if k in rec}}


def kept_load(layer) -> dict | None:
    """The load file and options kept with a probe Shapes layer (a project restored
    them there), or None."""
    load = (getattr(layer, "metadata", None) or {}).get(LOAD_KEY)
    return load if isinstance(load, dict) and load.get("path") else None


def keep_load(layer, options: dict) -> None:
    """Keep the probe dock's load file and options with its probe Shapes layer (a
    project saves them from there); the metadata is written only when they change."""
    if layer is not None and kept_load(layer) != options:
        layer.metadata = {**layer.metadata, LOAD_KEY: dict(options)}
