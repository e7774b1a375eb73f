"""One SEM pair measured with the corrections in the order the microscope
applied the errors: scan-line shifts (estimated on the raw rows), then each
image's drift, then the correlation, then the spatial distortion."""

from __future__ import annotations

from ..core.images import as_gray_float
from ..core.params import DICParams
from ..core.results import DICResult
from ..dic.correlate import correlate
from .distortion import DistortionError, DistortionModel, correct_distortion
from .drift import DriftModel
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
                    scan_lines: bool = False, drift: DriftModel | None = None,
                    start_times=None):
    """The pair with scan-line shifts and drift removed, and what was removed:
    ``(reference, deformed, ScanLines | None, meta)``."""
    f, g = as_gray_float(reference, "reference"), as_gray_float(deformed, "deformed")
    meta: dict = {}
    lines = None
    times = _start_times(drift, f, g, start_times) if drift is not None else None
    if scan_lines:
        lines = find_scan_lines(f, g, roi, params)
        f, g = remove_scan_lines(f, lines.reference), remove_scan_lines(g, lines.deformed)
        meta["scan_lines"] = lines.to_meta()
    if drift is not None:
        f, g = drift.remove(f, times[0]), drift.remove(g, times[1])
        meta["drift"] = {"reference": drift.summary(times[0]),
                         "deformed": drift.summary(times[1])}
    return f, g, lines, meta


def correlate_sem(reference, deformed, roi=None, params: DICParams | None = None, *,
                  distortion: DistortionModel | None = None, scan_lines: bool = False,
                  drift: DriftModel | None = None, start_times=None,
                  **kwargs) -> DICResult:
    """``correlate`` of an SEM pair with its corrections: ``scan_lines``
    estimates and removes both images' scan-line shifts, ``drift`` removes
    each image's drift (scan start times from the drift series, or
    ``start_times = (t_ref, t_def)``), ``distortion`` reports u, v in
    undistorted specimen coordinates. ``kwargs`` go to ``correlate``.
    ``meta["sem"]`` records every correction (line shifts per image)."""
    params = params or DICParams()
    if distortion is not None:
        distortion.check_shape(as_gray_float(reference).shape, "the images")
    f, g, lines, meta = sem_corrections(reference, deformed, roi, params,
                                        scan_lines=scan_lines, drift=drift,
                                        start_times=start_times)
    res = correlate(f, g, roi=roi, params=params, **kwargs)
    if distortion is not None:
        res = correct_distortion(res, distortion)
    res.meta.setdefault("sem", {}).update(meta)
    return res


def scan_lines_of(result: DICResult) -> ScanLines | None:
    """The scan-line shifts recorded in a result, or None."""
    d = result.meta.get("sem", {}).get("scan_lines")
    return None if d is None else ScanLines.from_meta(d)
