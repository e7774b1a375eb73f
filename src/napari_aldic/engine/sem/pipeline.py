"""One SEM pair measured with its corrections: scan-line shifts (estimated on
the raw rows and removed from them), the correlation, then the spatial
distortion and each image's drift applied to the measured displacements."""

from __future__ import annotations

import dataclasses

from ..core.images import as_gray_float
from ..core.params import DICParams
from ..core.results import DICResult
from ..dic.correlate import correlate
from .distortion import DistortionError, DistortionModel
from .drift import DriftModel
from .positions import SumMap, correct_positions
from .scanlines import ScanLines, find_scan_lines, remove_scan_lines

__all__ = ["correlate_sem", "sem_corrections", "scan_lines_of"]


def _start_times(drift: DriftModel, f, g, start_times):
    if start_times is not None:
        if len(start_times) != 2:
            raise DistortionError("give two start times: the reference's and the deformed "
                                  "image's")
        return float(start_times[0]), float(start_times[1])
    times = drift.start_time_of(f), drift.start_time_of(g)
    for name, t in zip(("reference", "deformed"), times):
        if t is None:
            raise DistortionError(f"the {name} image is not in the drift calibration's series: "
                                  "give the start time of its scan (seconds on the drift "
                                  "series' clock)")
    return times


def sem_corrections(reference, deformed, roi=None, params: DICParams | None = None, *,
                    scan_lines: bool = False):
    """The pair with its scan-line shifts removed (when asked), and them:
    ``(reference, deformed, ScanLines | None)``."""
    f, g = as_gray_float(reference, "reference"), as_gray_float(deformed, "deformed")
    if not scan_lines:
        return f, g, None
    lines = find_scan_lines(f, g, roi, params)
    return remove_scan_lines(f, lines.reference), remove_scan_lines(g, lines.deformed), lines


def correlate_sem(reference, deformed, roi=None, params: DICParams | None = None, *,
                  distortion: DistortionModel | None = None, scan_lines: bool = False,
                  drift: DriftModel | None = None, start_times=None,
                  **kwargs) -> DICResult:
    """``correlate`` of an SEM pair with its corrections: ``scan_lines``
    estimates and removes both images' scan-line shifts (rows resampled),
    then ``distortion`` and ``drift`` (each image's own, scan start times from
    the drift series or ``start_times = (t_ref, t_def)``) move the measured
    u, v to undistorted specimen coordinates in one step (:mod:`.positions`).
    ``kwargs`` go to ``correlate``. ``meta["sem"]`` records every correction
    (the line shifts per image)."""
    params = params or DICParams()
    fields = {f.name for f in dataclasses.fields(DICParams)}
    given = {k: kwargs.pop(k) for k in list(kwargs) if k in fields}
    if given:  # subset, step, ... also for the scan-line rounds
        params = params.replace(**given)
    shape = as_gray_float(reference).shape
    if distortion is not None:
        distortion.check_shape(shape, "the images")
    times = None
    if drift is not None:
        drift.check_shape(shape)
        times = _start_times(drift, reference, deformed, start_times)
    f, g, lines = sem_corrections(reference, deformed, roi, params, scan_lines=scan_lines)
    res = correlate(f, g, roi=roi, params=params, **kwargs)
    meta: dict = {}
    if lines is not None:
        meta["scan_lines"] = lines.to_meta()
    if distortion is not None or drift is not None:
        maps = [SumMap(distortion, None if drift is None else drift.at(t))
                for t in (times or (0.0, 0.0))]
        res = correct_positions(res, *maps)
        if distortion is not None:
            meta["distortion"] = distortion.summary()
        if drift is not None:
            meta["drift"] = {"reference": drift.summary(times[0]),
                             "deformed": drift.summary(times[1])}
    res.meta.setdefault("sem", {}).update(meta)
    return res


def scan_lines_of(result: DICResult) -> ScanLines | None:
    """The scan-line shifts recorded in a result, or None."""
    d = result.meta.get("sem", {}).get("scan_lines")
    return None if d is None else ScanLines.from_meta(d)
