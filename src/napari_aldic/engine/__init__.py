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

import lazy_loader

#: where each public name lives. Imported on first use (PEP 562, through
#: ``lazy_loader``): ``import napari_aldic.engine`` costs milliseconds, and a
#: command imports the parts it uses only (issue 25: the command line starts
#: compiling the kernels before SciPy and the readers are loaded).
_WHERE = {
    "core.compiling": ["compile_seconds", "is_compiling"],
    "core.files": ["EncoderNotFoundError", "ExportError", "InputFileError", "RunFolderError"],
    "core.params": ["DICParams", "StrainParams"],
    "core.progress": ["Cancelled", "ProgressEvent"],
    "core.reasons": ["DICError", "Reason"],
    "core.results": ["DICResult", "SequenceResult", "load_result"],
    "core.settings": ["Settings"],
    "core.units": ["Units"],
    "core.volresults": ["VolumeResult"],
    "dic.correlate": ["correlate"],
    "dic.noise_floor": ["noise_floor"],
    "dic.quadtree": ["Refinement", "resolve_refinement"],
    "dic.quality": ["SubsetAdvice", "advise_subset"],
    "dic.strain": ["StrainResult", "compute_strain"],
    "io.runs": ["load_run"],
    "io.settings_file": ["read_settings", "write_settings"],
    "io.stack": ["open_stack"],
    "sem": ["correct_distortion", "correlate_sem"],
    "volume": ["VolumeStrain", "compute_strain_volume", "correlate_volume", "export_volume",
               "track_volumes"],
    "viz.report": ["export_report"],
    "workflow.export": ["export_result"],
    "workflow.precompile": ["precompile_kernels"],
    "workflow.sequence": ["TrackError", "track"],
    "workflow.tiled": ["correlate_tiled", "needs_tiling"],
    "workflow.watch": ["watch"],
    "workflow.watch_probes": ["LiveProbes"],
}
_lazy_getattr, __dir__, _ = lazy_loader.attach(
    __name__, submodules=["io", "probes", "sem", "synthetic", "viz"], submod_attrs=_WHERE)


def __getattr__(name: str):
    try:
        return _lazy_getattr(name)
    except AttributeError:  # Python's own wording, as for any module
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None

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
