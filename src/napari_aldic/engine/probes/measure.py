"""Probe values over the frames of a run: gauges, points, areas, profiles.

Line gauges (gauge points ``p0``, ``p1``, their displacements ``d0``, ``d1``,
``e = (p1 - p0)/|p1 - p0|``, ``n`` = ``e`` rotated by +90 degrees, ``L = |p1 - p0|``,
``l = |p1 + d1 - p0 - d0|``):

* ``strain`` = (l - L) / L (engineering), ``true_strain`` = ln(1 + strain),
  ``elongation`` = l - L (length unit);
* crack opening displacement: ``cod_opening`` = (d1 - d0)·e,
  ``cod_sliding`` = (d1 - d0)·n, ``cod_magnitude`` = |d1 - d0| (length unit).

With the gauge drawn *across* a crack, ``cod_opening`` is the relative motion
of the two faces along the gauge (a gauge normal to the crack measures its
opening), ``cod_sliding`` the motion across the gauge.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core.reasons import Reason
from ..core.settings import STRAIN_DEFAULTS
from ..core.units import Units
from ..dic.strain import compute_strain
from ..io.columns import FIELD_INFO, unit_of
from ..io.runs import Frame, collect_frames
from ..viz.figures import field_values
from .geometry import LineProbe, ProbeSet, polyline_points
from .sampling import DEGRADED, MISSING, OK, FrameSampler, segment_in_roi, worst
from .table import Column, ProbeTable

__all__ = ["measure_probes", "kymograph", "Kymograph", "DEFAULT_FIELDS", "STATISTICS",
           "LINE_QUANTITIES", "probe_frames"]

#: fields a point or area probe reports by default
DEFAULT_FIELDS = ("u", "v", "exx", "eyy", "exy")
#: statistics of an area probe, per field
STATISTICS = ("mean", "median", "min", "max", "std", "valid_fraction")
#: line gauge quantities: name -> (kind of unit, description)
LINE_QUANTITIES = {
    "strain": ("none", "engineering strain (l - L) / L"),
    "true_strain": ("none", "true (logarithmic) strain ln(1 + strain)"),
    "elongation": ("length", "elongation l - L"),
    "cod_opening": ("length", "crack opening (d1 - d0)·e"),
    "cod_sliding": ("length", "crack sliding (d1 - d0)·n"),
    "cod_magnitude": ("length", "crack opening magnitude |d1 - d0|"),
}
_STRAIN_FIELDS = {k for k, (_, kind) in FIELD_INFO.items() if kind in ("strain", "angle")}
#: area probes with fewer trusted nodes than this are degraded
MIN_TRUSTED_FRACTION = 0.5


def _check_fields(fields) -> tuple[str, ...]:
    fields = tuple(fields)
    bad = [f for f in fields if f not in FIELD_INFO]
    if bad:
        raise ValueError(f"unknown field(s) {bad} for point/area probes; choose from "
                         f"{', '.join(FIELD_INFO)}")
    return fields


def _zero_frame(first: Frame, strain_opts: dict | None) -> Frame:
    """Frame 0 (the reference, a zero field) on the nodes of ``first``."""
    res = first.result
    z = np.zeros(len(res))
    small = np.asarray(res.reason) == int(Reason.SMALL_COMPONENT)
    zero = replace(res, u=z, v=z.copy(), dudx=z.copy(), dudy=z.copy(), dvdx=z.copy(),
                   dvdy=z.copy(), zncc=np.where(small, np.nan, 1.0), valid=~small,
                   reason=np.where(small, int(Reason.SMALL_COMPONENT), 0).astype(np.int8),
                   meta={**res.meta, "frame": 0}, u_local=None, v_local=None)
    strain = None if strain_opts is None else compute_strain(zero, **strain_opts)
    return Frame(0, zero, strain)


def probe_frames(data, *, strain=False, units=None, frames=None):
    """``(frames, units, info)`` of ``data`` (as :func:`~napari_aldic.engine.io.collect_frames`)
    with the reference first: frame 0 (a zero field) is added when it is not stored."""
    fr, units, info = collect_frames(data, strain=strain, units=units, frames=frames)
    fr = list(fr)
    first = fr[0].result
    moved = np.any(np.nan_to_num(first.u[first.valid])) or np.any(
        np.nan_to_num(first.v[first.valid]))
    # a first frame with a zero field is the reference itself (e.g. a widget run from
    # frame 5); otherwise the reference, frame 0, is added
    if fr[0].index > 0 and moved and (frames is None or 0 in frames):
        s = info.get("strain")
        opts = None if strain is False or strain is None else (
            {"window": s["window"], "method": s["method"], "measure": s["measure"]} if s
            else dict(STRAIN_DEFAULTS))
        fr.insert(0, _zero_frame(fr[0], opts))
    return fr, units, info


def measure_probes(data, probes: ProbeSet, *, fields=DEFAULT_FIELDS, strain=None,
                   units=None, frames=None) -> ProbeTable:
    """Values of every probe at every frame of ``data``.

    Parameters
    ----------
    data : result, SequenceResult, list of results, result file or run folder
    probes : ProbeSet
        Probes in reference-image pixels.
    fields : sequence of str
        Fields that point and area probes report (``u``, ``v``, ``magnitude``,
        ``exx``, ``eyy``, ``exy``, ``e1``, ``e2``, ``max_shear``, ``von_mises``,
        ``rotation``, ``zncc``); line gauges always give their six quantities.
    strain : None, bool or dict of compute_strain options
        ``None`` computes strain (default settings) only when a point or area
        probe needs a strain field.
    units : Units or dict, optional
        Defaults to the units stored with the results (else pixels).
    frames : iterable of int, optional
        Frame numbers to keep (default all; frame 0 is added as the zero field).

    Returns
    -------
    ProbeTable
        Columns ``line{i}_strain``, ``line{i}_true_strain``, ``line{i}_elongation``,
        ``line{i}_cod_opening``, ``line{i}_cod_sliding``, ``line{i}_cod_magnitude``;
        ``point{i}_{field}``; ``area{i}_{field}_{statistic}`` (:data:`STATISTICS`).
    """
    if not isinstance(probes, ProbeSet):
        raise TypeError(f"probes must be a ProbeSet, not {type(probes).__name__}")
    fields = _check_fields(fields)
    spatial = bool(probes.points or probes.areas)
    if strain is None:
        strain = spatial and any(f in _STRAIN_FIELDS for f in fields)
    if not strain and spatial:
        fields = tuple(f for f in fields if f not in _STRAIN_FIELDS)
    fr_list, units, info = probe_frames(data, strain=strain, units=units, frames=frames)
    table = ProbeTable([f.index for f in fr_list], units=units, probes=probes,
                       info={"source": info.get("source"), "strain": info.get("strain"),
                             "fields": list(fields)})
    n = len(fr_list)
    probed = ([_LineGauge(f"line{i}", line, n, units) for i, line in enumerate(probes.lines, 1)]
              + [_PointProbe(f"point{i}", pt, fields, n, units)
                 for i, pt in enumerate(probes.points, 1)]
              + [_AreaProbe(f"area{i}", area, fields, n, units)
                 for i, area in enumerate(probes.areas, 1)])
    # frame by frame, every probe at once: a run read from its folder is then
    # read once, one frame at a time (memory flat in the number of frames)
    for k, (fr, smp) in enumerate(zip(fr_list, _samplers(fr_list))):
        for probe in probed:
            probe.add(k, fr, smp)
    for probe in probed:
        for col in probe.columns():
            table.add(col)
    return table


def _samplers(fr_list):
    """A :class:`FrameSampler` per frame, made when needed (each reuses the
    previous one's cells and search tree when the nodes are the same)."""
    prev = None
    for f in fr_list:
        prev = FrameSampler(f.result, like=prev)
        yield prev


def _field_unit(name: str, units: Units) -> str:
    return unit_of(FIELD_INFO[name][1], units)


# ------------------------------------------------------------------ line gauges
class _LineGauge:
    """A line gauge's six quantities, filled frame by frame."""

    def __init__(self, label: str, line: LineProbe, n: int, units: Units):
        self.label, self.line, self.units = label, line, units
        self.vals = {q: np.full(n, np.nan) for q in LINE_QUANTITIES}
        self.status = np.full(n, MISSING, np.int8)
        self.reasons = [""] * n
        self.gauge_status = np.full(n, MISSING, np.int8)
        self.gauge_reasons = [""] * n
        self.px = np.array([line.x0, line.x1])
        self.py = np.array([line.y0, line.y1])

    def add(self, k: int, fr, smp: FrameSampler) -> None:
        line, units, px, py, vals = self.line, self.units, self.px, self.py, self.vals
        e, nrm, L = line.direction, line.normal, line.length
        su = smp.sample(field_values(fr, "u", Units()), px, py)
        sv = smp.sample(field_values(fr, "v", Units()), px, py)
        st, why = worst(su, sv)
        for j, name in enumerate(("start point", "end point")):
            if why[j]:
                why[j] = f"{name}: {why[j]}"
        self.status[k] = st.max()
        self.reasons[k] = "; ".join(w for w in why if w)
        d = np.array([su.values[1] - su.values[0], sv.values[1] - sv.values[0]])
        chord = np.array([px[1] - px[0], py[1] - py[0]]) + d
        ell = float(np.hypot(*chord))
        vals["strain"][k] = (ell - L) / L
        vals["true_strain"][k] = np.log1p(vals["strain"][k]) if ell > 0 else np.nan
        vals["elongation"][k] = (ell - L) * units.pixel_size
        vals["cod_opening"][k] = float(d @ e) * units.pixel_size
        vals["cod_sliding"][k] = float(d @ nrm) * units.pixel_size
        vals["cod_magnitude"][k] = float(np.hypot(*d)) * units.pixel_size
        self.gauge_status[k], self.gauge_reasons[k] = self.status[k], self.reasons[k]
        if self.status[k] != MISSING and fr.index > 0 and \
                not segment_in_roi(smp.roi, px[0], py[0], px[1], py[1]):
            self.gauge_status[k] = max(self.gauge_status[k], DEGRADED)
            self.gauge_reasons[k] = "; ".join(filter(None, [
                self.reasons[k], "a crack or hole (outside the ROI) lies between the gauge "
                "points: the strain includes its opening"]))

    def columns(self) -> list:
        cols = []
        for q, (kind, desc) in LINE_QUANTITIES.items():
            gauge = q in ("strain", "true_strain", "elongation")
            cols.append(Column(f"{self.label}_{q}", self.label, self.vals[q],
                               self.units.unit if kind == "length" else "",
                               self.gauge_status if gauge else self.status,
                               self.gauge_reasons if gauge else self.reasons, desc))
        return cols


# ------------------------------------------------------------------ points
class _PointProbe:
    """A point probe's fields, filled frame by frame."""

    def __init__(self, label: str, pt, fields, n: int, units: Units):
        self.label, self.pt, self.fields, self.units = label, pt, fields, units
        self.vals = {f: np.full(n, np.nan) for f in fields}
        self.status = {f: np.full(n, MISSING, np.int8) for f in fields}
        self.reasons = {f: [""] * n for f in fields}

    def add(self, k: int, fr, smp: FrameSampler) -> None:
        for name in self.fields:
            s = smp.sample(field_values(fr, name, self.units), [self.pt.x], [self.pt.y])
            self.vals[name][k], self.status[name][k] = s.values[0], s.status[0]
            self.reasons[name][k] = s.reasons[0]

    def columns(self) -> list:
        pt = self.pt
        return [Column(f"{self.label}_{name}", self.label, self.vals[name],
                       _field_unit(name, self.units), self.status[name], self.reasons[name],
                       f"{FIELD_INFO[name][0]} at ({pt.x:g}, {pt.y:g})")
                for name in self.fields]


# ------------------------------------------------------------------ areas
def _area_stats(values: np.ndarray, inside: np.ndarray) -> tuple[dict, int, str]:
    """Statistics of the finite values of the nodes ``inside``; (stats, status, reason)."""
    n_in = int(inside.sum())
    v = values[inside]
    v = v[np.isfinite(v)]
    stats = dict.fromkeys(STATISTICS, np.nan)
    if n_in == 0:
        return stats, MISSING, "no node inside the area (smaller than the node spacing?)"
    stats["valid_fraction"] = v.size / n_in
    if v.size == 0:
        return stats, MISSING, f"none of the {n_in} nodes in the area is trusted"
    stats.update(mean=v.mean(), median=np.median(v), min=v.min(), max=v.max(), std=v.std())
    if stats["valid_fraction"] < MIN_TRUSTED_FRACTION:
        return stats, DEGRADED, (f"only {v.size} of the {n_in} nodes in the area are "
                                 "trusted")
    return stats, OK, ""


class _AreaProbe:
    """An area probe's statistics of each field, filled frame by frame."""

    def __init__(self, label: str, area, fields, n: int, units: Units):
        self.label, self.area, self.fields, self.units = label, area, fields, units
        self.stats = {f: {s: np.full(n, np.nan) for s in STATISTICS} for f in fields}
        self.status = {f: np.full(n, MISSING, np.int8) for f in fields}
        self.reasons = {f: [""] * n for f in fields}

    def add(self, k: int, fr, smp: FrameSampler) -> None:
        inside = self.area.contains(fr.result.x, fr.result.y)
        for name in self.fields:
            st, self.status[name][k], self.reasons[name][k] = _area_stats(
                field_values(fr, name, self.units), inside)
            for s in STATISTICS:
                self.stats[name][s][k] = st[s]

    def columns(self) -> list:
        out = []
        for name in self.fields:
            unit, status = _field_unit(name, self.units), self.status[name]
            for s in STATISTICS:
                values = self.stats[name][s]
                # the trusted fraction is known even when no value is (0 of n nodes)
                col_status = np.where(np.isfinite(values), np.minimum(status, DEGRADED),
                                      MISSING) if s == "valid_fraction" else status
                out.append(Column(f"{self.label}_{name}_{s}", self.label, values,
                                  "" if s == "valid_fraction" else unit, col_status,
                                  self.reasons[name],
                                  f"{s} of {FIELD_INFO[name][0]} in the area"))
        return out


# ------------------------------------------------------------------ profiles
@dataclass
class Kymograph:
    """A field sampled along a polyline at every frame (a profile per row).

    ``values[i, j]`` is the field at point j (``x[j]``, ``y[j]`` in reference
    pixels, ``distance[j]`` along the polyline in ``units.unit``) at frame
    ``frames[i]``; ``status`` holds the codes (0 ok, 1 degraded, 2 missing).
    """

    frames: np.ndarray
    distance: np.ndarray
    x: np.ndarray
    y: np.ndarray
    values: np.ndarray
    status: np.ndarray
    field: str
    unit: str
    units: Units


def kymograph(data, vertices, field: str = "u", *, spacing: float = 1.0, strain=None,
              units=None, frames=None) -> Kymograph:
    """``field`` along the polyline ``vertices`` (reference pixels, or a
    :class:`LineProbe`) every ``spacing`` px, at every frame of ``data``
    (``frames=[k]`` gives the profile of frame k)."""
    if isinstance(vertices, LineProbe):
        vertices = [(vertices.x0, vertices.y0), (vertices.x1, vertices.y1)]
    field = _check_fields([field])[0]
    if strain is None:
        strain = field in _STRAIN_FIELDS
    x, y, dist = polyline_points(vertices, spacing)
    fr_list, units, _ = probe_frames(data, strain=strain, units=units, frames=frames)
    vals = np.full((len(fr_list), x.size), np.nan)
    status = np.full(vals.shape, MISSING, np.int8)
    for i, (fr, smp) in enumerate(zip(fr_list, _samplers(fr_list))):
        s = smp.sample(field_values(fr, field, units), x, y)
        vals[i], status[i] = s.values, s.status
    return Kymograph(np.array([f.index for f in fr_list]), dist * units.pixel_size, x, y,
                     vals, status, field, _field_unit(field, units), units)
