"""npe2 writers for result layers (napari is not imported here).

Any result layer (``DIC u``, ``DIC displacement`` ...) carries the analysis
behind it; saving it writes that analysis, not the layer's pixels:

* ``.npz``: the engine's result format. A single deformed frame is written to
  the given file; a sequence is written as a folder named after the file
  (``results.npz`` -> ``results/frame_00000.npz``, ``frame_00001.npz`` ...),
  which the reader opens again as result layers with a time axis.
* ``.csv`` / ``.mat``: the engine's exports (one row per node per frame with
  strains; MATLAB structs), in the physical units set in the widget.
"""

from __future__ import annotations

from pathlib import Path

from .i18n import tr

__all__ = ["write_results", "write_export", "units_of", "save_analysis"]


def _analysis_of(meta: dict):
    analysis = (meta.get("metadata") or {}).get("napari_aldic_analysis")
    if analysis is None:
        raise ValueError(tr("this layer holds no napari-aldic results; choose a 'DIC ...' "
                            "result layer"))
    return analysis


def units_of(info: dict | None):
    """The engine :class:`~napari_aldic.engine.Units` of a result layer's metadata."""
    from .engine import Units

    info = info or {}
    unit = str(info.get("length_unit", "px"))
    size = float(info.get("pixel_size", 1.0)) if unit != "px" else 1.0
    try:
        return Units(size, unit, info.get("frame_interval"), info.get("time_unit") or "s")
    except ValueError:
        return Units()


def write_results(path: str, data, meta: dict) -> list[str]:
    """Write the results behind a result layer as ``.npz`` file(s)."""
    analysis = _analysis_of(meta)
    return save_analysis(analysis, path, units_of((meta.get("metadata") or {}).get(
        "napari_aldic")))


def save_analysis(analysis, path, units) -> list[str]:
    """Write an analysis as the engine's ``.npz`` result file(s) with ``units``
    (:class:`~napari_aldic.engine.Units`): one file for a single deformed frame,
    else the folder named after ``path`` (``results.npz`` -> ``results/``) of
    ``frame_#####.npz`` files, which the reader opens again with a time axis."""
    units = units.to_dict()
    path = Path(path)
    if path.suffix.lower() != ".npz":
        path = path.with_suffix(".npz")
    done = [(k, r) for k, r in zip(analysis.frames, analysis.results) if r is not None]
    for _, r in done:
        r.meta["units"] = units  # read back by the reader and the engine's exports
    deformed = done[1:] if len(done) > 1 else done
    if len(deformed) == 1:
        return [str(deformed[0][1].save(path))]
    folder = path.with_suffix("")
    folder.mkdir(parents=True, exist_ok=True)
    return [str(r.save(folder / f"frame_{k:05d}.npz")) for k, r in done]


def write_export(path: str, data, meta: dict) -> list[str]:
    """Export the results behind a result layer as ``.csv`` or ``.mat`` (engine exports)."""
    from .engine import export_result

    analysis = _analysis_of(meta)
    info = (meta.get("metadata") or {}).get("napari_aldic") or {}
    results = [r for r in analysis.results if r is not None]
    s = analysis.strain
    out = export_result(results, path, units=units_of(info),
                        strain={"window": s.window, "method": s.method, "measure": s.measure})
    return [str(p) for p in out] if isinstance(out, (list, tuple)) else [str(out)]
