"""Probe shapes in reference-image pixels: points, line gauges, areas, polylines.

Coordinates follow the engine's convention (x = column, y = row, pixel centres
at integers) in the *reference* image (frame 0): a probe marks material points,
and its values at frame k are those of the same material (Lagrangian).

A :class:`ProbeSet` is what a user draws; it round-trips through plain JSON
dictionaries (:meth:`ProbeSet.to_dict` / :meth:`ProbeSet.from_dict`) for
parameter and project files.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["PointProbe", "LineProbe", "AreaProbe", "ProbeSet", "polyline_points",
           "AREA_KINDS"]

AREA_KINDS = ("rectangle", "ellipse", "polygon")


def _finite(values, what: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: {values!r} must be numbers (pixels)") from None
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"{what}: {values!r} must be finite numbers (pixels)")
    return out


@dataclass(frozen=True)
class PointProbe:
    """One material point ``(x, y)``: the value of a field there."""

    x: float
    y: float
    name: str = ""

    def __post_init__(self):
        x, y = _finite((self.x, self.y), f"point probe {self.name or ''}".strip())
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "y", y)

    def to_dict(self) -> dict:
        return {"kind": "point", "name": self.name, "xy": [self.x, self.y]}


@dataclass(frozen=True)
class LineProbe:
    """A virtual extensometer between the gauge points ``(x0, y0)`` and ``(x1, y1)``.

    Its gauge quantities come from the displacements ``d0``, ``d1`` of the two
    points only (a crack between them is measured, not smoothed away).
    """

    x0: float
    y0: float
    x1: float
    y1: float
    name: str = ""

    def __post_init__(self):
        vals = _finite((self.x0, self.y0, self.x1, self.y1),
                       f"line probe {self.name or ''}".strip())
        for k, v in zip(("x0", "y0", "x1", "y1"), vals):
            object.__setattr__(self, k, v)
        if self.length == 0:
            raise ValueError(f"line probe {self.name or ''} ({vals}): its two gauge points are "
                             "the same; give two distinct points")

    @property
    def length(self) -> float:
        """Gauge length in pixels."""
        return math.hypot(self.x1 - self.x0, self.y1 - self.y0)

    @property
    def direction(self) -> np.ndarray:
        """Unit vector ``e`` from the first to the second gauge point."""
        return np.array([self.x1 - self.x0, self.y1 - self.y0]) / self.length

    @property
    def normal(self) -> np.ndarray:
        """``e`` rotated by +90 degrees (from +x towards +y)."""
        ex, ey = self.direction
        return np.array([-ey, ex])

    def to_dict(self) -> dict:
        return {"kind": "line", "name": self.name,
                "xy": [[self.x0, self.y0], [self.x1, self.y1]]}


@dataclass(frozen=True)
class AreaProbe:
    """A region: ``rectangle`` (x0, y0, x1, y1), ``ellipse`` (cx, cy, rx, ry, angle
    in degrees from +x towards +y) or ``polygon`` (vertices). Its statistics use
    the nodes inside it."""

    kind: str
    params: tuple
    name: str = ""

    def __post_init__(self):
        if self.kind not in AREA_KINDS:
            raise ValueError(f"area probe kind {self.kind!r} must be one of {AREA_KINDS}")
        what = f"{self.kind} area probe {self.name or ''}".strip()
        if self.kind == "polygon":
            pts = np.asarray(self.params, float)
            if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3:
                raise ValueError(f"{what}: give at least three (x, y) vertices")
            vals = tuple(_finite(p, what) for p in pts)
        else:
            n = 4 if self.kind == "rectangle" else 5
            p = tuple(self.params) + ((0.0,) if self.kind == "ellipse"
                                      and len(self.params) == 4 else ())
            if len(p) != n:
                raise ValueError(f"{what}: give {n} numbers, not {len(self.params)}")
            vals = _finite(p, what)
            if self.kind == "rectangle":
                x0, y0, x1, y1 = vals
                vals = (min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1))
                if vals[0] == vals[2] or vals[1] == vals[3]:
                    raise ValueError(f"{what}: the rectangle has no area")
            elif vals[2] <= 0 or vals[3] <= 0:
                raise ValueError(f"{what}: the radii must be > 0")
        object.__setattr__(self, "params", vals)

    @classmethod
    def rectangle(cls, x0, y0, x1, y1, name: str = "") -> AreaProbe:
        return cls("rectangle", (x0, y0, x1, y1), name)

    @classmethod
    def circle(cls, cx, cy, r, name: str = "") -> AreaProbe:
        return cls("ellipse", (cx, cy, r, r, 0.0), name)

    @classmethod
    def ellipse(cls, cx, cy, rx, ry, angle_deg: float = 0.0, name: str = "") -> AreaProbe:
        return cls("ellipse", (cx, cy, rx, ry, angle_deg), name)

    @classmethod
    def polygon(cls, vertices, name: str = "") -> AreaProbe:
        return cls("polygon", tuple(map(tuple, np.asarray(vertices, float))), name)

    def contains(self, x, y) -> np.ndarray:
        """True for the points ``(x, y)`` inside the area (edges included)."""
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        if self.kind == "rectangle":
            x0, y0, x1, y1 = self.params
            return (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
        if self.kind == "ellipse":
            cx, cy, rx, ry, ang = self.params
            c, s = math.cos(math.radians(ang)), math.sin(math.radians(ang))
            dx, dy = x - cx, y - cy
            a, b = c * dx + s * dy, -s * dx + c * dy
            return (a / rx) ** 2 + (b / ry) ** 2 <= 1.0 + 1e-12
        from matplotlib.path import Path

        path = Path(np.asarray(self.params, float))
        pts = np.column_stack([x.ravel(), y.ravel()])
        # a tiny positive radius counts points on the boundary as inside
        return path.contains_points(pts, radius=1e-9).reshape(x.shape) | \
            path.contains_points(pts, radius=-1e-9).reshape(x.shape)

    def outline(self, n: int = 64) -> np.ndarray:
        """(m, 2) closed outline ``(x, y)`` for drawing."""
        if self.kind == "rectangle":
            x0, y0, x1, y1 = self.params
            return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]], float)
        if self.kind == "ellipse":
            cx, cy, rx, ry, ang = self.params
            t = np.linspace(0, 2 * np.pi, n + 1)
            c, s = math.cos(math.radians(ang)), math.sin(math.radians(ang))
            a, b = rx * np.cos(t), ry * np.sin(t)
            return np.column_stack([cx + c * a - s * b, cy + s * a + c * b])
        pts = np.asarray(self.params, float)
        return np.vstack([pts, pts[:1]])

    def to_dict(self) -> dict:
        params = [list(p) for p in self.params] if self.kind == "polygon" else list(self.params)
        return {"kind": "area", "shape": self.kind, "name": self.name, "params": params}


@dataclass
class ProbeSet:
    """The probes of an analysis: points, line gauges and areas (each numbered
    from 1 in its own kind: ``point1``, ``line1``, ``area1``, ...)."""

    points: list = field(default_factory=list)
    lines: list = field(default_factory=list)
    areas: list = field(default_factory=list)

    def __post_init__(self):
        for what, items, cls in (("points", self.points, PointProbe),
                                 ("lines", self.lines, LineProbe),
                                 ("areas", self.areas, AreaProbe)):
            bad = [type(p).__name__ for p in items if not isinstance(p, cls)]
            if bad:
                raise TypeError(f"ProbeSet.{what} holds {bad[0]}, not {cls.__name__}")

    def __len__(self) -> int:
        return len(self.points) + len(self.lines) + len(self.areas)

    def labels(self) -> list[tuple[str, object]]:
        """``(label, probe)`` of every probe: ``line1``, ..., ``point1``, ..., ``area1``."""
        out = [(f"line{i}", p) for i, p in enumerate(self.lines, 1)]
        out += [(f"point{i}", p) for i, p in enumerate(self.points, 1)]
        out += [(f"area{i}", p) for i, p in enumerate(self.areas, 1)]
        return out

    def to_dict(self) -> dict:
        """Plain JSON: ``{"format": "napari-aldic-probes", "version": 1, "probes": [...]}``
        with reference-image pixel coordinates."""
        items = [p.to_dict() for p in (*self.lines, *self.points, *self.areas)]
        return {"format": "napari-aldic-probes", "version": 1, "coordinates":
                "reference-image pixels, x = column, y = row", "probes": items}

    @classmethod
    def from_dict(cls, d: dict) -> ProbeSet:
        """Inverse of :meth:`to_dict` (a bare list of probe dictionaries works too)."""
        items = d.get("probes", []) if isinstance(d, dict) else d
        out = cls()
        for i, item in enumerate(items):
            try:
                kind, name = item["kind"], item.get("name", "")
                if kind == "point":
                    out.points.append(PointProbe(*item["xy"], name=name))
                elif kind == "line":
                    (x0, y0), (x1, y1) = item["xy"]
                    out.lines.append(LineProbe(x0, y0, x1, y1, name=name))
                elif kind == "area":
                    params = item["params"]
                    if item["shape"] == "polygon":
                        params = tuple(map(tuple, params))
                    out.areas.append(AreaProbe(item["shape"], tuple(params), name=name))
                else:
                    raise ValueError(f"unknown kind {kind!r} (point, line or area)")
            except (KeyError, TypeError, ValueError) as exc:
                raise ValueError(f"probe {i + 1} of the probe set is not valid: {exc}") from None
        return out


def polyline_points(vertices, spacing: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points every ``spacing`` pixels along a polyline (vertices included).

    Returns ``(x, y, distance)`` with the distance from the first vertex along
    the polyline, in pixels.
    """
    v = np.asarray(vertices, float)
    if v.ndim != 2 or v.shape[1] != 2 or len(v) < 2:
        raise ValueError("a profile needs a polyline of at least two (x, y) vertices")
    if not np.all(np.isfinite(v)):
        raise ValueError("the profile's vertices must be finite numbers")
    if not spacing > 0:
        raise ValueError(f"spacing={spacing!r} must be > 0 pixels")
    seg = np.hypot(*np.diff(v, axis=0).T)
    if seg.sum() == 0:
        raise ValueError("the profile polyline has zero length")
    v = np.vstack([v[:1], v[1:][seg > 0]])  # repeated vertices add nothing
    seg = seg[seg > 0]
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(2, int(math.ceil(cum[-1] / spacing)) + 1)
    d = np.unique(np.concatenate([np.linspace(0.0, cum[-1], n), cum]))
    return np.interp(d, cum, v[:, 0]), np.interp(d, cum, v[:, 1]), d
