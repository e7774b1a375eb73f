"""napari-free DIC engine: NumPy/SciPy/Numba only (no napari, no Qt).

The public API is what this module exports (``__all__``), plus the curated
subpackages :mod:`~napari_aldic.engine.io` (file formats, run folders, image
stacks), :mod:`~napari_aldic.engine.viz` (figures, media, PDF report) and
:mod:`~napari_aldic.engine.synthetic` (exact-truth speckle images)::

    from napari_aldic.engine import correlate, track, compute_strain
    res = correlate(reference, deformed, subset=31, step=8, method="aldic")

Layout, by role (imports flow downwards only; see docs/architecture.md):

* ``core/``      value types and validation: parameters, results, units, reasons,
  settings, atomic file writes, progress/cancel;
* ``kernels/``   every Numba kernel (numpy/numba only);
* ``dic/``       the algorithm, one module per step of Algorithm 1;
* ``io/``        image stacks, run folders and every result file format;
* ``viz/``       matplotlib figures, PNG/GIF/MP4 and the PDF report;
* ``workflow/``  what strings the steps together: ``track``, ``export_result`` and
  ``correlate_tiled`` (pairs larger than memory, block by block);
* ``synthetic/`` exact-truth images and the named demo cases.
"""

from __future__ import annotations

import importlib
import warnings

from . import io, probes, synthetic, viz
from .core.compiling import compile_seconds, is_compiling
from .core.files import EncoderNotFoundError, ExportError, RunFolderError
from .core.params import DICParams
from .core.progress import Cancelled, ProgressEvent
from .core.reasons import Reason
from .core.results import DICResult, SequenceResult, load_result
from .core.settings import Settings
from .core.units import Units
from .dic.correlate import correlate
from .dic.noise_floor import noise_floor
from .dic.quadtree import Refinement, resolve_refinement
from .dic.quality import SubsetAdvice, advise_subset
from .dic.strain import StrainResult, compute_strain
from .io.runs import load_run
from .io.settings_file import load_params, save_params
from .io.stack import open_stack
from .viz.report import export_report
from .workflow.export import export_result
from .workflow.sequence import TrackError, track
from .workflow.tiled import correlate_tiled, needs_tiling

__all__ = [
    # analysis
    "correlate", "correlate_tiled", "needs_tiling", "track", "compute_strain", "DICParams",
    "Settings", "Refinement",
    "resolve_refinement", "Cancelled", "ProgressEvent",
    "compile_seconds", "is_compiling",
    # measurement quality
    "advise_subset", "SubsetAdvice", "noise_floor",
    # results
    "DICResult", "SequenceResult", "StrainResult", "Reason", "Units", "load_result",
    "load_run", "open_stack",
    # files
    "export_result", "export_report", "save_params", "load_params",
    "ExportError", "EncoderNotFoundError", "TrackError", "RunFolderError",
    # subpackages
    "io", "viz", "synthetic", "probes",
]

#: names this module exported before the engine was split into subpackages;
#: still importable (with a DeprecationWarning naming the new home)
_MOVED = {
    "as_gray_float": "core.images", "prefilter": "dic.interpolation",
    "sample": "dic.interpolation", "SplineImage": "dic.interpolation",
    "displacement_figure": "viz.figures", "plot_displacement": "viz.figures",
    "field_figure": "viz.figures", "export_png": "viz.media", "export_gif": "viz.media",
    "export_mp4": "viz.media", "export_csv": "io.csv", "read_csv": "io.csv",
    "export_mat": "io.matlab", "load_mat": "io.runs", "export_vtu": "io.vtk",
    "read_vtu": "io.vtk", "export_davis": "io.davis", "load_settings": "io.settings_file",
    "collect_frames": "io.runs",
}


def __getattr__(name: str):
    if name in _MOVED:
        public = "viz" if _MOVED[name].startswith("viz") else "io"
        if _MOVED[name].startswith(("core", "dic")):
            public = _MOVED[name]
        warnings.warn(f"napari_aldic.engine.{name} moved: import it from "
                      f"napari_aldic.engine.{public}", DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(f".{_MOVED[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
