"""Probes: numbers over time from a result or a run folder (napari-free).

Point probes, line gauges (virtual extensometers with crack opening
displacement) and area probes, in reference-image pixels; per-frame values with
a status and a reason; line profiles and kymographs; testing-machine load data
synchronised with the frames; CSV and plot exports::

    from napari_aldic.engine.probes import LineProbe, ProbeSet, measure_probes
    table = measure_probes("run_folder", ProbeSet(lines=[LineProbe(40, 100, 220, 100)]))
    table["line1_strain"]          # one value per frame (NaN where missing)
    table.columns["line1_strain"].status_text

See docs/probes.md for the definitions.
"""

from ..viz.probe_page import draw_kymograph, draw_probe_curves, draw_stress_strain, probe_figure
from .export import export_kymograph_csv, export_kymograph_plot, export_probe_plot
from .geometry import AREA_KINDS, AreaProbe, LineProbe, PointProbe, ProbeSet, polyline_points
from .load import LOAD_UNITS, LoadRecord, attach_load, load_at_frames, read_load_csv
from .measure import (
    DEFAULT_FIELDS,
    LINE_QUANTITIES,
    STATISTICS,
    Kymograph,
    kymograph,
    measure_probes,
    probe_frames,
)
from .sampling import DEGRADED, MISSING, OK, STATUS_NAMES, FrameSampler, Sampled
from .table import Column, ProbeTable, export_probes_csv, probe_csv_lines

__all__ = [
    # probes
    "PointProbe", "LineProbe", "AreaProbe", "ProbeSet", "AREA_KINDS", "polyline_points",
    # measuring
    "measure_probes", "probe_frames", "kymograph", "Kymograph", "ProbeTable", "Column",
    "FrameSampler", "Sampled", "DEFAULT_FIELDS", "STATISTICS", "LINE_QUANTITIES",
    "OK", "DEGRADED", "MISSING", "STATUS_NAMES",
    # load data
    "read_load_csv", "LoadRecord", "load_at_frames", "attach_load", "LOAD_UNITS",
    # exports
    "export_probes_csv", "export_kymograph_csv", "export_probe_plot", "export_kymograph_plot",
    "probe_csv_lines",
    # drawing (matplotlib axes)
    "draw_probe_curves", "draw_stress_strain", "draw_kymograph", "probe_figure",
]
