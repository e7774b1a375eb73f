"""Probes from napari layers, measured on the analysis shown in the viewer (no Qt).

* :func:`find_analysis`: the :class:`~napari_aldic._analysis.Analysis` behind the
  ``DIC ...`` result layers (made by the widget or by opening a result), with the
  transform from world coordinates to reference-image pixels and frames;
* :func:`probes_from_layers`: a Shapes layer (line = gauge; rectangle, ellipse,
  polygon = area) and a Points layer (point probes) as a
  :class:`~napari_aldic.engine.probes.ProbeSet` in reference-image pixels;
* :func:`measure_analysis`: the probe table of that analysis, reusing its strain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..engine import Units
from ..engine.io import Frame, FrameSet
from ..engine.probes import (
    AreaProbe,
    LineProbe,
    PointProbe,
    ProbeSet,
    attach_load,
    measure_probes,
    read_load_csv,
)
from ..i18n import tr
from .project import is_probe_layer
from .project_results import kept_load

__all__ = ["image_view", "ResultView", "find_analysis", "probes_from_layers", "measure_analysis",
           "is_probe_candidate", "probe_table", "PROBE_SHAPES", "PROBE_POINTS"]

ANALYSIS_KEY = "napari_aldic_analysis"
#: names of the layers that "Add probe layers" makes
PROBE_SHAPES = "probes"
PROBE_POINTS = "probe points"


@dataclass
class ResultView:
    """An analysis in the viewer and where its pixels and frames are in the world.

    World ``(row, col)`` = ``translate + scale * (y, x)`` for reference pixels
    ``(x, y)``; world time = ``t_translate + t_scale * frame`` (``t_scale`` None
    without a time axis).
    """

    analysis: object
    scale: np.ndarray
    translate: np.ndarray
    t_scale: float | None
    t_translate: float
    units: Units
    layer: object  # the result layer it was read from

    def to_pixels(self, world) -> tuple[float, float]:
        """Reference-image pixel ``(x, y)`` of a world position (last two axes)."""
        rc = (np.asarray(world, float)[-2:] - self.translate) / self.scale
        return float(rc[1]), float(rc[0])

    def frame_at(self, world_t: float) -> int:
        if self.t_scale is None:
            return int(self.analysis.frames[-1])
        return int(round((world_t - self.t_translate) / self.t_scale))

    def world_time(self, frame: int) -> float | None:
        return None if self.t_scale is None else self.t_translate + frame * self.t_scale


def _units_of(meta: dict) -> Units:
    unit = meta.get("length_unit") or "px"
    size = float(meta.get("pixel_size") or 1.0)
    try:
        return Units(size if unit != "px" else 1.0, unit, meta.get("frame_interval") or None,
                     meta.get("time_unit") or "s")
    except ValueError:
        return Units()


def image_view(image_layer) -> ResultView:
    """A view of an image layer's pixels (no analysis): where its pixels are in the world."""
    return ResultView(analysis=None, scale=np.asarray(image_layer.scale, float)[-2:],
                      translate=np.asarray(image_layer.translate, float)[-2:], t_scale=None,
                      t_translate=0.0, units=Units(), layer=image_layer)


def find_analysis(layers) -> ResultView | None:
    """The analysis of the first ``DIC`` field (Image) layer in ``layers``, or None."""
    for layer in layers:
        analysis = (getattr(layer, "metadata", None) or {}).get(ANALYSIS_KEY)
        if analysis is None or layer.__class__.__name__ != "Image":
            continue
        base = analysis.lattice()
        if base is None:
            continue
        step = float(base.params.step)
        scale = np.asarray(layer.scale[-2:], float) / step
        grid0 = np.array([float(base.grid_ys[0]), float(base.grid_xs[0])])
        translate = np.asarray(layer.translate[-2:], float) - grid0 * scale
        timed = layer.ndim == 3
        meta = layer.metadata.get("napari_aldic") or {}
        return ResultView(analysis, scale, translate,
                          float(layer.scale[0]) if timed else None,
                          float(layer.translate[0]) if timed else 0.0, _units_of(meta), layer)
    return None


def is_probe_candidate(layer) -> bool:
    """Points and Shapes layers that are not result layers."""
    return layer.__class__.__name__ in ("Points", "Shapes") and \
        not str(layer.name).startswith("DIC ")


def _pixels(layer, vertices, view: ResultView) -> np.ndarray:
    """(n, 2) reference pixels ``(x, y)`` of a layer's data vertices."""
    return np.array([view.to_pixels(layer.data_to_world(v)) for v in np.asarray(vertices)])


def _ellipse(xy: np.ndarray) -> AreaProbe:
    """napari's ellipse: the four corners of its (possibly rotated) bounding box."""
    c = xy.mean(axis=0)
    a, b = 0.5 * (xy[1] - xy[0]), 0.5 * (xy[2] - xy[1])
    rx, ry = float(np.hypot(*a)), float(np.hypot(*b))
    ang = (math.degrees(math.atan2(a[1], a[0])) + 90.0) % 180.0 - 90.0  # in [-90, 90)
    if abs(ang) > 45.0:  # the same ellipse, told with the angle nearest 0
        rx, ry, ang = ry, rx, ang - math.copysign(90.0, ang)
    return AreaProbe.ellipse(c[0], c[1], rx, ry, ang + 0.0)


def _shape_probe(kind: str, xy: np.ndarray, name: str):
    if kind == "line" or (kind == "path" and len(xy) == 2):
        return LineProbe(*xy[0], *xy[-1], name=name)
    if kind == "rectangle":
        x0, y0 = xy.min(axis=0)
        x1, y1 = xy.max(axis=0)
        edges = np.diff(np.vstack([xy, xy[:1]]), axis=0)
        if np.all(np.min(np.abs(edges), axis=1) < 1e-9):  # axis-aligned
            return AreaProbe.rectangle(x0, y0, x1, y1, name=name)
        return AreaProbe.polygon(xy, name=name)
    if kind == "ellipse":
        return _ellipse(xy)
    if kind == "polygon":
        return AreaProbe.polygon(xy, name=name)
    return None


def probes_from_layers(shapes, points, view: ResultView) -> tuple[ProbeSet, list[str]]:
    """Probes of a Shapes and a Points layer (either may be None) in reference
    pixels, and notes on shapes that are not probes."""
    probes, notes = ProbeSet(), []
    if shapes is not None:
        for i, (kind, data) in enumerate(zip(shapes.shape_type, shapes.data)):
            try:
                p = _shape_probe(kind, _pixels(shapes, data, view), f"{shapes.name} #{i + 1}")
            except ValueError as exc:
                notes.append(tr("shape {number} of '{layer}' skipped: {exc}").format(
                                    number=i + 1, layer=shapes.name, exc=exc))
                continue
            if p is None:
                notes.append(tr("shape {number} of '{layer}' ({kind}) is not a probe: draw a "
                                "line (gauge) or a rectangle, ellipse or polygon (area)").format(
                                    number=i + 1, layer=shapes.name, kind=kind))
            elif isinstance(p, LineProbe):
                probes.lines.append(p)
            else:
                probes.areas.append(p)
    if points is not None:
        for i, xy in enumerate(_pixels(points, points.data, view) if len(points.data) else []):
            probes.points.append(PointProbe(*xy, name=f"{points.name} #{i + 1}"))
    return probes, notes


def measure_analysis(view: ResultView, probes: ProbeSet, fields=("u", "v", "exx", "eyy",
                                                                 "exy")):
    """The probe table of the frames computed so far (strain as the analysis has it)."""
    a = view.analysis
    frames = []
    for i, (k, res) in enumerate(zip(a.frames, a.results)):
        if res is None:
            continue
        strain = a.strains[i] if i < len(a.strains) else None
        frames.append(Frame(int(k), res, strain))
    if not frames:
        raise ValueError(tr("the analysis has no computed frame yet"))
    has_strain = all(f.strain is not None for f in frames)
    if not has_strain:
        fields = tuple(f for f in fields if f in ("u", "v", "magnitude", "zncc"))
    data = FrameSet(frames, view.units, {"source": getattr(a, "source", "")})
    settings = getattr(a, "strain", None)
    strain = has_strain and {"window": settings.window, "method": settings.method,
                             "measure": settings.measure}
    return measure_probes(data, probes, fields=fields, strain=strain or False,
                          units=view.units)


def probe_table(layers):
    """The probe table of the viewer's probe layers (the first marked Shapes and
    Points layers) on the analysis shown, with the load file kept with the probe
    Shapes layer (the probe dock's CSV): the widget's PDF report gets its probe
    page from it. None without an analysis or probes."""
    view = find_analysis(layers)
    if view is None or view.analysis is None:
        return None
    kinds = {"Shapes": None, "Points": None}
    for lay in layers:
        kind = lay.__class__.__name__
        if is_probe_layer(lay) and kinds.get(kind, 0) is None:
            kinds[kind] = lay
    probes, _ = probes_from_layers(kinds["Shapes"], kinds["Points"], view)
    if not len(probes):
        return None
    table = measure_analysis(view, probes)
    load = kept_load(kinds["Shapes"])
    if load and load.get("area_mm2"):
        try:
            attach_load(table, read_load_csv(load["path"]), area_mm2=float(load["area_mm2"]),
                        sync=load.get("sync"), fps=load.get("fps"),
                        offset=float(load.get("offset") or 0.0))
        except (ValueError, OSError):  # the probe dock says why; the page has no stress
            pass
    return table
