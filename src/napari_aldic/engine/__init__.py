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
    "plot_displacement",
]
