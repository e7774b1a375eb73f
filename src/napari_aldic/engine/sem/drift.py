"""Beam drift during the raster scan: calibration from a time series of images
of the undeformed area and correction of each image by its own drift.

Model (docs/sem.md). Pixel ``(x, y)`` of an image whose scan starts at time
``t0`` (seconds on one clock for the whole session) is acquired at
``t = t0 + y * line_time + x * dwell`` and shows the specimen position
``x - delta(t)``; the drift ``delta`` is a polynomial in time without constant
term (``delta(0) = 0``: the gauge). A point seen at ``x0`` in image 0 and at
``x1 = x0 + u`` in image ``k`` of the series gives, exactly and linearly,

    ``u = delta(t_k + tau(x1)) - delta(t_0 + tau(x0))``,  ``tau(x) = y line_time + x dwell``,

which is solved by least squares over the trusted nodes of every image
correlated with image 0. A measurement is corrected without resampling
either image (:mod:`.positions`): ``U = u - delta(t_def + tau(x0 + u)) +
delta(t_ref + tau(x0))``, each image by its own drift at its own scan time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.files import array_digest
from ..core.images import as_gray_float
from ..core.params import DICParams
from ..core.results import DICResult
from ..dic.correlate import correlate
from .distortion import DistortionError, read_calibration, robust_lstsq, write_calibration
from .positions import correct_positions

__all__ = ["ScanTiming", "DriftModel", "calibrate_drift", "correct_drift", "load_drift",
           "scan_timing"]

FORMAT = "napari-aldic-sem-drift"
VERSION = 1
_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "\u03bcs": 1e-6, "ns": 1e-9}


@dataclass
class ScanTiming:
    """Raster timing: seconds per pixel and per line (line = columns x dwell
    plus the fly-back)."""

    dwell: float
    line_time: float

    def __post_init__(self):
        if not (self.dwell >= 0 and self.line_time > 0):
            raise DistortionError(f"scan timing dwell={self.dwell} s, line time="
                                  f"{self.line_time} s: both must be positive")

    def pixel_time(self, x, y, t0: float = 0.0):
        return t0 + np.asarray(y, float) * self.line_time + np.asarray(x, float) * self.dwell

    def frame_time(self, rows: int) -> float:
        return rows * self.line_time


def _seconds(value, unit: str = "s") -> float:
    return float(value) * _UNITS.get(str(unit).strip(), 1.0)


def scan_timing(path) -> ScanTiming | None:
    """Dwell and line time from an FEI (Thermo) or Zeiss SEM TIFF, or None."""
    import tifffile

    with tifffile.TiffFile(str(path)) as tf:
        cols = tf.pages.first.shape[-1]
        fei, zeiss = tf.fei_metadata, tf.sem_metadata
    if fei:
        for section in ("Scan", "EScan", "IScan"):
            sec = fei.get(section) or {}
            dwell = sec.get("Dwelltime") or sec.get("DwellTime")
            if dwell:
                line = sec.get("LineTime") or dwell * cols
                return ScanTiming(float(dwell), float(line))
    if zeiss:
        found = {}
        for val in zeiss.values():
            if isinstance(val, tuple) and len(val) >= 2 and isinstance(val[1], (int, float)):
                name = str(val[0]).lower()
                unit = val[2] if len(val) >= 3 else "s"
                if "dwell" in name:
                    found.setdefault("dwell", _seconds(val[1], unit))
                elif "line time" in name:
                    found.setdefault("line", _seconds(val[1], unit))
        if "dwell" in found:
            return ScanTiming(found["dwell"], found.get("line", found["dwell"] * cols))
    return None


@dataclass
class DriftModel:
    """Fitted drift ``delta(t) = sum_i c_i (t / t_scale)^i``, ``i = 1..degree`` (px)."""

    degree: int
    timing: ScanTiming
    image_shape: tuple[int, int]
    t_scale: float
    coef_x: np.ndarray
    coef_y: np.ndarray
    residual_rms: float = float("nan")
    images: list = field(default_factory=list)  # [{"name", "sha256", "start_time_s"}]

    def _basis(self, t) -> np.ndarray:
        s = np.ravel(np.asarray(t, float)) / self.t_scale
        return np.stack([s ** (i + 1) for i in range(self.degree)], axis=1)

    def displacement(self, t):
        """``delta(t)`` in pixels."""
        shape = np.shape(t)
        B = self._basis(t)
        return (B @ self.coef_x).reshape(shape), (B @ self.coef_y).reshape(shape)

    def start_time_of(self, image) -> float | None:
        """The start time recorded for ``image`` if it is one of the series."""
        digest = array_digest(as_gray_float(image))
        for im in self.images:
            if im.get("sha256") == digest:
                return float(im["start_time_s"])
        return None

    def rate(self, t):
        """``d delta / dt`` in px/s."""
        s = np.ravel(np.asarray(t, float)) / self.t_scale
        B = np.stack([(i + 1) * s**i for i in range(self.degree)], axis=1) / self.t_scale
        return B @ self.coef_x, B @ self.coef_y

    def at(self, start_time: float) -> _DriftMap:
        """The position map of an image whose scan started at ``start_time``:
        pixel ``x`` shows specimen ``x - delta(start_time + tau(x))``."""
        return _DriftMap(self, float(start_time))

    def check_shape(self, shape) -> None:
        if tuple(shape) != tuple(self.image_shape):
            raise DistortionError(f"the drift calibration is for {self.image_shape[1]} x "
                                  f"{self.image_shape[0]} px images, these are "
                                  f"{shape[1]} x {shape[0]} px")

    # ------------------------------------------------------------ files
    def to_dict(self) -> dict:
        return {"format": FORMAT, "version": VERSION, "model": "polynomial in time",
                "degree": self.degree, "t_scale_s": self.t_scale,
                "dwell_s": self.timing.dwell, "line_time_s": self.timing.line_time,
                "image_shape": list(self.image_shape),
                "coef_x": [float(c) for c in self.coef_x],
                "coef_y": [float(c) for c in self.coef_y],
                "residual_rms_px": float(self.residual_rms), "images": self.images,
                "convention": "pixel (x, y) scanned at t0 + y line_time + x dwell shows "
                              "specimen (x, y) - delta(t); delta(0) = 0; px"}

    @classmethod
    def from_dict(cls, d: dict, source: str = "the drift file") -> DriftModel:
        if d.get("format") != FORMAT:
            raise DistortionError(f"{source} is not a napari-aldic drift calibration "
                                  f"(format {d.get('format')!r})")
        if int(d.get("version", 0)) > VERSION:
            raise DistortionError(f"{source} has version {d['version']}, newer than this "
                                  f"napari-aldic reads ({VERSION})")
        return cls(int(d["degree"]), ScanTiming(float(d["dwell_s"]), float(d["line_time_s"])),
                   tuple(int(n) for n in d["image_shape"]), float(d["t_scale_s"]),
                   np.asarray(d["coef_x"], float), np.asarray(d["coef_y"], float),
                   float(d.get("residual_rms_px", np.nan)), list(d.get("images", [])))

    def save(self, path) -> Path:
        return write_calibration(path, self.to_dict())

    def summary(self, start_time: float) -> dict:
        h, w = self.image_shape
        t = self.timing.pixel_time(np.array([0.0, w - 1.0]), np.array([0.0, h - 1.0]),
                                   start_time)
        dx, dy = self.displacement(t)
        return {"model": "polynomial in time", "degree": self.degree,
                "start_time_s": float(start_time),
                "drift_over_image_px": [float(dx[1] - dx[0]), float(dy[1] - dy[0])],
                "residual_rms_px": float(self.residual_rms)}


@dataclass
class _DriftMap:
    """One image's drift as a map of pixel positions (see :mod:`.positions`)."""

    model: DriftModel
    start_time: float

    def displacement(self, x, y):
        return self.model.displacement(self.model.timing.pixel_time(x, y, self.start_time))

    def jacobian(self, x, y):
        rx, ry = self.model.rate(self.model.timing.pixel_time(x, y, self.start_time))
        dwell, line = self.model.timing.dwell, self.model.timing.line_time
        return rx * dwell, rx * line, ry * dwell, ry * line


def correct_drift(result: DICResult, model: DriftModel, start_times) -> DICResult:
    """``result`` with displacements (and subset gradients) free of each image's
    drift: ``U = u - delta(t_def + tau(x + u)) + delta(t_ref + tau(x))``,
    ``start_times = (t_ref, t_def)`` in seconds on the drift series' clock."""
    model.check_shape(result.image_shape)
    t_ref, t_def = (float(t) for t in start_times)
    out = correct_positions(result, model.at(t_ref), model.at(t_def))
    out.meta.setdefault("sem", {})["drift"] = {"reference": model.summary(t_ref),
                                               "deformed": model.summary(t_def)}
    return out


def load_drift(path) -> DriftModel:
    """Read a drift calibration written by :meth:`DriftModel.save`."""
    return DriftModel.from_dict(read_calibration(path, "drift"), str(path))


def calibrate_drift(images, timing: ScanTiming, start_times=None, degree: int = 3,
                    params: DICParams | None = None, names=None, gap: float = 0.0,
                    progress=None, distortion=None) -> DriftModel:
    """Fit the drift from images of the undeformed, unmoved area (image 0 is
    the reference). ``start_times`` (s, one clock): default back to back,
    ``t_k = k (rows * line_time + gap)``. With a ``distortion`` model the
    correlations are corrected for it first (the drift moves the area across
    the distorted field: ``grad D * delta``, ~0.01 px for 4 px of drift)."""
    images = [as_gray_float(im, f"drift image {k}") for k, im in enumerate(images)]
    if len(images) < 2:
        raise DistortionError("give at least 2 drift images (3 or more recommended)")
    shape = images[0].shape
    if any(im.shape != shape for im in images):
        raise DistortionError("the drift images differ in size")
    if start_times is None:
        start_times = [k * (timing.frame_time(shape[0]) + gap) for k in range(len(images))]
    start_times = [float(t) for t in start_times]
    if len(start_times) != len(images):
        raise DistortionError(f"{len(start_times)} start times for {len(images)} drift images")
    span = max(start_times) + timing.frame_time(shape[0]) - min(0.0, min(start_times))
    model = DriftModel(int(degree), timing, shape, float(span), np.zeros(degree),
                       np.zeros(degree))
    rows, bu, bv = [], [], []
    for k in range(1, len(images)):
        if progress is not None:
            progress((k - 1) / (len(images) - 1), f"drift image {k}")
        res = correlate(images[0], images[k], params=params or DICParams())
        if distortion is not None:
            res = correct_positions(res, distortion, distortion)
        ok = res.valid & np.isfinite(res.u) & np.isfinite(res.v)
        x0, y0, u, v = res.x[ok], res.y[ok], res.u[ok], res.v[ok]
        t1 = timing.pixel_time(x0 + u, y0 + v, start_times[k])
        t0 = timing.pixel_time(x0, y0, start_times[0])
        rows.append(model._basis(t1) - model._basis(t0))
        bu.append(u)
        bv.append(v)
    A = np.vstack(rows)
    cx, _, rx = robust_lstsq(A, np.concatenate(bu))
    cy, _, ry = robust_lstsq(A, np.concatenate(bv))
    model.coef_x, model.coef_y, model.residual_rms = cx, cy, float(np.hypot(rx, ry))
    names = list(names) if names is not None else [f"image {k}" for k in range(len(images))]
    model.images = [{"name": str(n), "sha256": array_digest(im), "start_time_s": t}
                    for n, im, t in zip(names, images, start_times)]
    return model
