"""Synthetic DIC cases with exact truth, shared by the CLI demo and the sample data.

Only NumPy and the engine are imported here (no napari), so the command line
and the napari sample-data contributions build exactly the same images.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import speckle as synthetic

__all__ = ["CASES", "SyntheticCase", "crack_roi", "make_field", "make_case"]

#: displacement fields the demo knows, first one is the default
CASES = ("strain", "translation", "sinusoid", "crack")


@dataclass
class SyntheticCase:
    """A rendered reference/deformed pair and the field that relates them."""

    kind: str
    description: str
    field: object  # an engine.synthetic.DisplacementField
    reference: np.ndarray
    deformed: np.ndarray
    roi: np.ndarray | None  # True = analysed; None = whole image


def crack_roi(shape: tuple[int, int], tip: tuple[float, float], half_width: int = 1) -> np.ndarray:
    """ROI mask of a :class:`~napari_aldic.engine.synthetic.ModeICrack` image.

    The crack runs from the left edge to ``tip = (x, y)`` along row ``y``; a
    slot ``2 * half_width + 1`` pixels high along it is excluded (False).
    """
    roi = np.ones(shape, bool)
    tx, ty = int(round(tip[0])), int(round(tip[1]))
    roi[max(0, ty - half_width):ty + half_width + 1, :tx + 1] = False
    return roi


def make_field(kind: str, shape: tuple[int, int]):
    """Displacement field ``kind`` sized for an image of ``shape``.

    Returns ``(field, description)``.
    """
    rows, cols = shape
    cx, cy = cols / 2.0, rows / 2.0
    if kind == "strain":
        exx, eyy, angle, t = 0.01, -0.003, 0.5, (0.35, -0.6)
        field = synthetic.Affine.strain_rotation(exx=exx, eyy=eyy, angle_deg=angle,
                                                 center=(cx, cy), t=t)
        desc = (f"uniform strain exx={exx:.1%}, eyy={eyy:.1%}, rotation {angle} deg "
                f"about ({cx:g}, {cy:g}), translation ({t[0]}, {t[1]}) px")
    elif kind == "translation":
        field = synthetic.Translation(1.35, -0.6)
        desc = f"rigid translation u={field.u} px, v={field.v} px"
    elif kind == "sinusoid":
        wavelength = float(max(96.0, cols / 2.0))
        field = synthetic.Sinusoid(amplitude_u=0.8, amplitude_v=0.5, wavelength=wavelength)
        desc = (f"sinusoid u=0.8 sin(2 pi x/{wavelength:g}), v=0.5 sin(2 pi y/{wavelength:g}) px")
    elif kind == "crack":
        tip = (float(round(0.6 * cols)), float(rows // 2))
        field = synthetic.ModeICrack(tip=tip, amplitude=0.05, t=(0.3, 0.2))
        desc = (f"Mode-I crack from the left edge to the tip at ({tip[0]:g}, {tip[1]:g}), "
                f"opening {field.opening(0.0):.2f} px at the edge")
    else:
        raise ValueError(f"unknown synthetic field {kind!r}; choose one of {', '.join(CASES)}")
    return field, desc


def make_case(kind: str = "strain", shape=(512, 512), noise: float = 0.0,
              seed: int = 0, n_quad: int = 4) -> SyntheticCase:
    """Render the synthetic case ``kind`` (see :data:`CASES`).

    ``noise`` is the standard deviation of independent Gaussian noise in grey
    levels added to each 8-bit image; ``n_quad`` the Gauss-Legendre points
    per pixel axis of the rendering (fewer is faster, slightly less exact).
    """
    if np.isscalar(shape):
        shape = (int(shape), int(shape))
    shape = (int(shape[0]), int(shape[1]))
    if min(shape) < 48:
        raise ValueError(f"synthetic image size {shape} is too small; use at least 48 px")
    if noise < 0:
        raise ValueError(f"noise={noise} must be >= 0 grey levels")

    field, desc = make_field(kind, shape)
    ref, dfm = synthetic.speckle_pair(shape, field, noise=noise, seed=seed, n_quad=n_quad)
    roi = crack_roi(shape, field.tip) if kind == "crack" else None
    return SyntheticCase(kind, desc, field, ref, dfm, roi)
