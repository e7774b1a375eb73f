"""HRDIC in the SEM: spatial distortion, scan-line shifts and drift (docs/sem.md).

* :mod:`.distortion` time-invariant field distortion ``D``: calibration from
  rigidly translated images, correction of measured displacements;
* :mod:`.scanlines` per-image x-shifts of scan lines, estimated from a pair;
* :mod:`.drift` beam drift as a polynomial in scan time, calibrated from a
  time series, removed from each measurement image by image;
* :mod:`.positions` measured displacements moved to specimen coordinates;
* :mod:`.pipeline` ``correlate_sem``: all three around ``correlate``.
"""

from .distortion import (
    DistortionError,
    DistortionModel,
    calibrate_distortion,
    correct_distortion,
    fit_distortion,
    load_distortion,
)
from .drift import (
    DriftModel,
    ScanTiming,
    calibrate_drift,
    correct_drift,
    load_drift,
    scan_timing,
)
from .pipeline import correlate_sem, scan_lines_of, sem_corrections
from .positions import SumMap, correct_positions
from .scanlines import (
    ScanLines,
    correlate_scan_lines,
    estimate_scan_lines,
    find_scan_lines,
    remove_scan_lines,
)

__all__ = [
    "DistortionError", "DistortionModel", "calibrate_distortion", "correct_distortion",
    "fit_distortion", "load_distortion",
    "DriftModel", "ScanTiming", "calibrate_drift", "correct_drift", "load_drift", "scan_timing",
    "correlate_sem", "scan_lines_of", "sem_corrections", "SumMap", "correct_positions",
    "ScanLines", "correlate_scan_lines", "estimate_scan_lines", "find_scan_lines",
    "remove_scan_lines",
]
