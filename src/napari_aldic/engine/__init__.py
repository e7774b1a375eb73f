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
* ``synthetic/`` exact-truth images and the named demo cases;
* ``sem/``       HRDIC in the SEM: distortion, scan-line shifts, drift.
"""

from __future__ import annotations

from . import io, probes, sem, synthetic, viz
from .core.compiling import compile_seconds, is_compiling
from .core.files import EncoderNotFoundError, ExportError, InputFileError, RunFolderError
from .core.params import DICParams, StrainParams
from .core.progress import Cancelled, ProgressEvent
from .core.reasons import DICError, Reason
from .core.results import DICResult, SequenceResult, load_result
from .core.settings import Settings
from .core.units import Units
from .core.volresults import VolumeResult
from .dic.correlate import correlate
from .dic.noise_floor import noise_floor
from .dic.quadtree import Refinement, resolve_refinement
from .dic.quality import SubsetAdvice, advise_subset
from .dic.strain import StrainResult, compute_strain
from .io.runs import load_run
from .io.settings_file import read_settings, write_settings
from .io.stack import open_stack
from .sem import correct_distortion, correlate_sem
from .viz.report import export_report
from .volume import (
    VolumeStrain,
    compute_strain_volume,
    correlate_volume,
    export_volume,
    track_volumes,
)
from .workflow.export import export_result
from .workflow.precompile import precompile_kernels
from .workflow.sequence import TrackError, track
from .workflow.tiled import correlate_tiled, needs_tiling
from .workflow.watch import watch
from .workflow.watch_probes import LiveProbes

__all__ = [
    # analysis
    "correlate", "correlate_tiled", "needs_tiling", "track", "compute_strain", "DICParams",
    "Settings", "Refinement", "StrainParams",
    "resolve_refinement", "Cancelled", "ProgressEvent",
    "compile_seconds", "is_compiling", "precompile_kernels",
    # measurement quality
    "advise_subset", "SubsetAdvice", "noise_floor",
    # results
    "DICResult", "SequenceResult", "StrainResult", "Reason", "Units", "load_result",
    "load_run", "open_stack",
    # files
    "export_result", "export_report", "read_settings", "write_settings",
    "ExportError", "EncoderNotFoundError", "TrackError", "RunFolderError", "DICError",
    "InputFileError",
    # subpackages
    "io", "viz", "synthetic", "probes",
    # HRDIC in the SEM (issue 27; calibration in engine.sem)
    "sem", "correlate_sem", "correct_distortion",
    # live DIC (issue 26)
    "watch", "LiveProbes",
    # volumes (DVC, issue 28)
    "correlate_volume", "VolumeResult", "compute_strain_volume", "VolumeStrain", "export_volume",
    "track_volumes",
]
