"""Exact-truth speckle images and displacement fields, and the named demo cases.

``speckle_pair(shape, field)`` renders a reference/deformed pair whose
displacement is known analytically everywhere; the field classes
(:class:`Translation`, :class:`Affine`, :class:`Sinusoid`, :class:`ModeICrack`,
:class:`PlateWithHole`, ...) give that truth at any node. ``make_case`` builds
the named cases shared by the CLI demo and the napari sample data.
"""

from .cases import CASES, SyntheticCase, crack_roi, make_case, make_field
from .sem import SEMScan, SEMView, random_line_shifts, sem_image
from .speckle import (
    Affine,
    DisplacementField,
    ModeICrack,
    PlateWithHole,
    Rotation,
    Sinusoid,
    SpecklePattern,
    Sum,
    Translation,
    make_pattern,
    render,
    speckle_pair,
)

__all__ = [
    "SpecklePattern", "make_pattern", "render", "speckle_pair", "DisplacementField",
    "Translation", "Affine", "Rotation", "Sinusoid", "ModeICrack", "PlateWithHole", "Sum",
    "CASES", "SyntheticCase", "crack_roi", "make_case", "make_field",
    "SEMScan", "SEMView", "sem_image", "random_line_shifts",
]
