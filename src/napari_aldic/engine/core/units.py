"""Physical units of a DIC analysis: pixel size and frame interval.

The engine computes in pixels of the reference image and in frame numbers.
:class:`Units` says what one pixel and one frame step are in physical terms;
every export (CSV headers, MATLAB variables, colour-bar labels, the PDF
report, VTK files) applies it the same way:

* lengths (node coordinates, displacements) are multiplied by
  ``pixel_size`` and labelled with ``unit``;
* times are ``frame * frame_interval`` in ``time_unit``;
* velocities (``unit / time_unit``) and strain rates (``1 / time_unit``) are
  only produced when ``frame_interval`` is given;
* strains and rotations are dimensionless (rotation in radians) and do not
  depend on the pixel size.

A result carries its units in ``result.meta["units"]`` (a plain dictionary,
saved with the ``.npz``): ``result.meta["units"] = Units(0.5, "um").to_dict()``;
exports use it when no ``units=`` argument is given.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

__all__ = ["Units"]


@dataclass(frozen=True)
class Units:
    """Pixel size and frame interval applied by every export.

    Attributes
    ----------
    pixel_size : float, default 1.0
        Length of one pixel in ``unit`` (e.g. ``0.05`` with ``unit="um"``
        for 50 nm pixels). Must be 1 when ``unit`` is ``"px"``.
    unit : str, default "px"
        Name of the length unit ("px", "nm", "um", "µm", "mm", ...).
    frame_interval : float or None, default None
        Time between consecutive frames in ``time_unit``; ``None`` when
        unknown (no times, velocities or strain rates are exported then).
    time_unit : str, default "s"
        Name of the time unit.
    """

    pixel_size: float = 1.0
    unit: str = "px"
    frame_interval: float | None = None
    time_unit: str = "s"

    def __post_init__(self) -> None:
        try:
            ps = float(self.pixel_size)
        except (TypeError, ValueError):
            raise ValueError(f"pixel_size={self.pixel_size!r} must be a positive number") from None
        if not (math.isfinite(ps) and ps > 0):
            raise ValueError(f"pixel_size={self.pixel_size!r} must be a positive number")
        object.__setattr__(self, "pixel_size", ps)
        if not isinstance(self.unit, str) or not self.unit.strip():
            raise ValueError(f"unit={self.unit!r} must be a non-empty name, e.g. 'um' or 'px'")
        object.__setattr__(self, "unit", self.unit.strip())
        if self.unit == "px" and ps != 1.0:
            raise ValueError(f"pixel_size={ps:g} needs a physical length unit (unit='um', 'mm', "
                             "...); with unit='px' the pixel size is 1")
        if self.frame_interval is not None:
            try:
                dt = float(self.frame_interval)
            except (TypeError, ValueError):
                raise ValueError(f"frame_interval={self.frame_interval!r} must be a positive "
                                 "number or None") from None
            if not (math.isfinite(dt) and dt > 0):
                raise ValueError(f"frame_interval={self.frame_interval!r} must be a positive "
                                 "number or None")
            object.__setattr__(self, "frame_interval", dt)
        if not isinstance(self.time_unit, str) or not self.time_unit.strip():
            raise ValueError(f"time_unit={self.time_unit!r} must be a non-empty name, e.g. 's'")
        object.__setattr__(self, "time_unit", self.time_unit.strip())

    # ------------------------------------------------------------ labels
    @property
    def has_time(self) -> bool:
        """True when a frame interval is known."""
        return self.frame_interval is not None

    @property
    def velocity_unit(self) -> str:
        return f"{self.unit}/{self.time_unit}"

    @property
    def rate_unit(self) -> str:
        return f"1/{self.time_unit}"

    def time(self, frame):
        """Time of frame number(s) ``frame`` (``None`` without a frame interval)."""
        if self.frame_interval is None:
            return None
        return frame * self.frame_interval

    def describe(self) -> str:
        """One line, e.g. ``"1 px = 0.5 um; frame interval 0.1 s"``."""
        length = ("lengths in pixels" if self.unit == "px"
                  else f"1 px = {self.pixel_size:g} {self.unit}")
        time = ("no frame interval (frame numbers only)" if self.frame_interval is None
                else f"frame interval {self.frame_interval:g} {self.time_unit}")
        return f"{length}; {time}"

    # ------------------------------------------------------------ I/O
    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dictionary."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> Units:
        """Units from a dictionary (``None`` or ``{}`` gives pixels, no time)."""
        if not d:
            return cls()
        names = {"pixel_size", "unit", "frame_interval", "time_unit"}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"unknown unit setting(s) {unknown}; valid names are {sorted(names)}")
        return cls(**d)

    @classmethod
    def from_meta(cls, meta: dict[str, Any] | None) -> Units | None:
        """Units stored in a result's ``meta["units"]``, else ``None``."""
        if not meta or not isinstance(meta.get("units"), dict):
            return None
        return cls.from_dict(meta["units"])
