"""napari-free DIC engine: NumPy/SciPy/Numba only (no napari, no Qt).

Public API::

    from napari_aldic.engine import correlate, DICParams, DICResult
"""

from . import synthetic
from .correlate import correlate
from .figures import displacement_figure, plot_displacement
from .images import as_gray_float
from .interpolation import SplineImage, prefilter, sample
from .params import DICParams
from .reasons import Reason
from .results import DICResult, load_result
from .strain import StrainResult, compute_strain
from .sequence import SequenceResult, open_stack, track
from .units import Units
from .progress import Cancelled
from .export import (EncoderNotFoundError, ExportError, collect_frames, export_csv,
                     export_davis, export_gif, export_mat, export_mp4, export_png,
                     export_result, export_vtu, field_figure, load_mat, load_params,
                     load_run, load_settings, read_csv, read_vtu, save_params)
from .report import export_report
from .quadtree import Refinement

__all__ = [
    "correlate",
    "track",
    "open_stack",
    "SequenceResult",
    "compute_strain",
    "StrainResult",
    "Refinement",
    "DICParams",
    "DICResult",
    "Reason",
    "load_result",
    "as_gray_float",
    "prefilter",
    "sample",
    "SplineImage",
    "synthetic",
    "displacement_figure",
    "Units",
    "Cancelled",
    "ExportError",
    "EncoderNotFoundError",
    "export_result",
    "export_mat",
    "load_mat",
    "export_csv",
    "read_csv",
    "export_vtu",
    "read_vtu",
    "export_davis",
    "export_png",
    "export_gif",
    "export_mp4",
    "field_figure",
    "save_params",
    "load_params",
    "load_settings",
    "load_run",
    "collect_frames",
    "export_report",
    "plot_displacement",
]
