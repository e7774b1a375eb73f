"""npe2 writers for result layers (napari is not imported here).

* ``.npz``: the results behind a result layer (``DIC u``, ``DIC displacement``
  ...), in the engine's result format. A single deformed frame is written to
  the given file; a sequence is written as a folder named after the file
  (``results.npz`` -> ``results/frame_00000.npz``, ``frame_00001.npz`` ...),
  which the reader opens again as result layers with a time axis.
* ``.csv``: the per-node table (``features``) of the ``DIC displacement``
  vectors layer: frame, node position, u, v, magnitude, ZNCC and strains, the
  length unit written into the column names.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

__all__ = ["write_results", "write_nodes_csv"]


def _analysis_of(meta: dict):
    analysis = (meta.get("metadata") or {}).get("napari_aldic_analysis")
    if analysis is None:
        raise ValueError("this layer holds no napari-aldic results; choose a 'DIC ...' "
                         "result layer")
    return analysis


def write_results(path: str, data, meta: dict) -> list[str]:
    """Write the results behind a result layer as ``.npz`` file(s)."""
    analysis = _analysis_of(meta)
    path = Path(path)
    if path.suffix.lower() != ".npz":
        path = path.with_suffix(".npz")
    done = [(k, r) for k, r in zip(analysis.frames, analysis.results) if r is not None]
    deformed = done[1:] if len(done) > 1 else done
    if len(deformed) == 1:
        return [str(deformed[0][1].save(path))]
    folder = path.with_suffix("")
    folder.mkdir(parents=True, exist_ok=True)
    return [str(r.save(folder / f"frame_{k:05d}.npz")) for k, r in done]


def write_nodes_csv(path: str, data, meta: dict) -> list[str]:
    """Write the per-node table of the ``DIC displacement`` layer as CSV."""
    info = (meta.get("metadata") or {}).get("napari_aldic")
    feats = meta.get("features")
    if info is None or feats is None:
        raise ValueError("this layer holds no napari-aldic node table; choose the "
                         "'DIC displacement' layer")
    unit = info.get("length_unit", "px")
    cols = list(feats.columns) if hasattr(feats, "columns") else list(feats)
    header = []
    for c in cols:
        if c in ("u", "v", "magnitude"):
            header.append(f"{c} [{unit}]")
        elif c in ("x_px", "y_px"):
            header.append(f"{c[0]} [px]")
        else:
            header.append(c)
    values = [np.asarray(feats[c]) for c in cols]
    path = Path(path)
    if path.suffix.lower() != ".csv":
        path = path.with_suffix(".csv")
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for row in zip(*values):
            w.writerow([f"{v:.9g}" if isinstance(v, (float, np.floating)) else v for v in row])
    return [str(path)]
