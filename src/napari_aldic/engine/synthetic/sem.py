"""Synthetic SEM images with exact truth: spatial distortion, drift in scan
time, scan-line shifts and noise, over the analytic speckle of :mod:`.speckle`.

The imaging model (all in pixels, x = column, y = row). The specimen sits on
a stage; a material point ``X`` (reference configuration) is at the *ideal*
position ``p = X + U(X)``, where ``U`` is the stage translation plus the
deformation. Pixel ``(x, y)`` of an image whose scan starts at time ``t0``
is acquired at ``t = t0 + y * line_time + x * dwell`` and shows the ideal
position

    ``p(x, y) = (x - L(y), y) - D(x, y) - drift(t)``

with ``D`` the time-invariant spatial distortion of the field of view (a
Brown-Conrady polynomial: radial ``k1 r^2``, ``k2 r^4`` and decentring
``p1, p2`` terms about the image centre, no constant or linear part), ``drift``
the beam's slow drift (a polynomial in time without constant term) and
``L(y)`` the x-jump of scan line ``y``. Each pixel is the area mean of the
analytic speckle at the material points of its quadrature points, so nothing
is interpolated: ``D``, ``drift``, ``L`` and ``U`` are the exact truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .speckle import DisplacementField, SpecklePattern, Translation, render

__all__ = ["SEMScan", "SEMView", "sem_image", "random_line_shifts"]


@dataclass
class SEMScan:
    """The microscope: distortion, drift and scan timing.

    ``k1, k2, p1, p2`` are Brown-Conrady coefficients over coordinates
    normalised by half the larger image side (so ``D`` in pixels is that
    half-side times the dimensionless polynomial). ``drift_x``/``drift_y`` are
    polynomial coefficients of ``t, t^2, ...`` (px/s, px/s^2, ...).
    """

    shape: tuple[int, int] = (1024, 1024)
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    dwell: float = 1e-6  # s per pixel
    flyback: float = 1e-4  # s between lines
    drift_x: tuple = ()
    drift_y: tuple = ()

    @property
    def line_time(self) -> float:
        return self.shape[1] * self.dwell + self.flyback

    @property
    def frame_time(self) -> float:
        return self.shape[0] * self.line_time

    def _normalised(self, x, y):
        h, w = self.shape
        s = max(h, w) / 2.0
        xi = (np.asarray(x, float) - (w - 1) / 2.0) / s
        return xi, (np.asarray(y, float) - (h - 1) / 2.0) / s, s

    def distortion(self, x, y):
        """``D(x, y)`` in pixels at image positions."""
        xi, eta, s = self._normalised(x, y)
        r2 = xi * xi + eta * eta
        radial = self.k1 * r2 + self.k2 * r2 * r2
        dx = xi * radial + self.p1 * (r2 + 2 * xi * xi) + 2 * self.p2 * xi * eta
        dy = eta * radial + self.p2 * (r2 + 2 * eta * eta) + 2 * self.p1 * xi * eta
        return s * dx, s * dy

    def drift(self, t):
        """Beam drift ``(dx, dy)`` in pixels at time ``t`` (s); zero at t = 0."""
        t = np.asarray(t, float)
        dx = sum(c * t ** (i + 1) for i, c in enumerate(self.drift_x)) + 0 * t
        dy = sum(c * t ** (i + 1) for i, c in enumerate(self.drift_y)) + 0 * t
        return dx, dy

    def pixel_time(self, x, y, t0: float = 0.0):
        return t0 + np.asarray(y, float) * self.line_time + np.asarray(x, float) * self.dwell


@dataclass
class SEMView(DisplacementField):
    """What one SEM image shows: ``inverse(x, y)`` maps pixel positions to the
    material points seen there (used by :func:`~.speckle.render`)."""

    scan: SEMScan
    motion: DisplacementField = field(default_factory=Translation)
    start_time: float = 0.0
    line_shifts: np.ndarray | None = None  # (rows,) px
    use_distortion: bool = True
    use_drift: bool = True

    def ideal(self, x, y):
        """Ideal (stage-frame) position shown at pixel position ``(x, y)``."""
        px, py = np.asarray(x, float).copy(), np.asarray(y, float).copy()
        if self.line_shifts is not None:
            row = np.clip(np.rint(y).astype(np.int64), 0, len(self.line_shifts) - 1)
            px = px - self.line_shifts[row]
        if self.use_distortion:
            dx, dy = self.scan.distortion(x, y)
            px, py = px - dx, py - dy
        if self.use_drift:
            dx, dy = self.scan.drift(self.scan.pixel_time(x, y, self.start_time))
            px, py = px - dx, py - dy
        return px, py

    def displacement(self, X, Y):
        return self.motion.displacement(X, Y)

    def inverse(self, x, y, iters: int = 60, tol: float = 1e-10):
        px, py = self.ideal(x, y)
        return self.motion.inverse(px, py)


def random_line_shifts(rows: int, fraction: float = 0.02, amplitude=(0.3, 1.0),
                       block=(2, 5), seed: int | None = 0) -> np.ndarray:
    """Scan-line x-jumps: ``fraction`` of the rows, in blocks of ``block``
    rows, each block shifted by ``±uniform(amplitude)`` pixels."""
    rng = np.random.default_rng(seed)
    out = np.zeros(rows)
    target = int(round(fraction * rows))
    while np.count_nonzero(out) < target:
        n = int(rng.integers(block[0], block[1] + 1))
        r0 = int(rng.integers(2, rows - n - 2))
        if np.any(out[max(0, r0 - 3):r0 + n + 3]):
            continue  # blocks apart, as a real glitch is one event
        out[r0:r0 + n] = rng.choice((-1.0, 1.0)) * rng.uniform(*amplitude)
    return out


def sem_image(pattern: SpecklePattern, scan: SEMScan, motion: DisplacementField | None = None,
              start_time: float = 0.0, line_shifts=None, noise: float = 0.0,
              seed: int | None = None, bit_depth: int | None = 8, n_quad: int = 3,
              use_distortion: bool = True, use_drift: bool = True) -> np.ndarray:
    """Render one SEM image of ``pattern`` after ``motion`` (stage translation
    plus deformation, Lagrangian; None = the reference configuration)."""
    view = SEMView(scan, motion if motion is not None else Translation(), start_time,
                   None if line_shifts is None else np.asarray(line_shifts, float),
                   use_distortion, use_drift)
    return render(pattern, scan.shape, view, n_quad=n_quad, noise=noise,
                  bit_depth=bit_depth, seed=seed)
