"""Exports of DIC results: MATLAB, CSV, VTK (.vtu), DaVis-style text, images, video.

Every function takes a result in any of these forms (``data``):

* one :class:`~napari_aldic.engine.core.results.DICResult` (an image pair);
* a :class:`~napari_aldic.engine.core.results.SequenceResult` from ``track``, or a
  list of ``DICResult`` (``None`` entries, frames not computed, are skipped);
* a path: a result ``.npz``, a ``.mat`` written by :func:`export_mat`, or a
  run folder (``sequence.json`` + ``frame_#####.npz`` written by
  ``track(out_dir=...)``, or the ``frame###.npz`` files of ``napari-aldic run``).

Units (:class:`~napari_aldic.engine.core.units.Units`: pixel size with its unit,
frame interval with its unit) are applied the same way by every export; see
``docs/exports.md`` for every file layout, field name and unit.

Every file is written under a temporary name in the target folder and renamed
when complete, so an interrupted or failed export (full disk, no permission)
never leaves a half-written file under the final name; such failures raise
:class:`ExportError` naming the file and what to do.
"""


from __future__ import annotations

import os
from pathlib import Path

from ..io.csv import export_csv
from ..io.davis import export_davis
from ..io.matlab import export_mat
from ..io.vtk import export_vtu
from ..viz.media import export_gif, export_mp4, export_png

# =================================================================== dispatch
_BY_SUFFIX = {".mat": "mat", ".csv": "csv", ".png": "png", ".gif": "gif", ".mp4": "mp4",
              ".pdf": "pdf", ".vtu": "vtu", ".txt": "davis"}


def export_result(data, path, to: str | None = None, **options):
    """Export ``data`` in the format named by ``to`` or by the suffix of
    ``path``: ``mat``, ``csv``, ``png``, ``gif``, ``mp4``, ``pdf`` (report),
    ``vtu`` or ``davis`` (``.txt``). ``options`` go to the writer."""
    fmt = to or _BY_SUFFIX.get(Path(os.fspath(path)).suffix.lower())
    if fmt is None:
        raise ValueError(f"cannot tell the export format of {path}; name it with to= one of "
                         f"{sorted(set(_BY_SUFFIX.values()))}")
    if fmt == "pdf":
        from ..viz.report import export_report

        return export_report(data, path, **options)
    writers = {"mat": export_mat, "csv": export_csv, "png": export_png, "gif": export_gif,
               "mp4": export_mp4, "vtu": export_vtu, "davis": export_davis}
    if fmt not in writers:
        raise ValueError(f"unknown export format {fmt!r}; choose one of "
                         f"{sorted(writers) + ['pdf']}")
    return writers[fmt](data, path, **options)
