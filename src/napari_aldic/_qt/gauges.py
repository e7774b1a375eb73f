"""The probe plot dock's gauge choice and its translated plot text and messages.

The engine draws the probe curves and gives the reasons of missing or degraded
probe values in English (it never imports the catalogues, and its CSV files keep
English); the dock says them in the user's language here: each English text of
the engine is a message id (:data:`ENGINE_TEXTS`), read back with its values
(:func:`~napari_aldic.i18n.retranslate.say_english`). The gauge of the
stress-strain curve is chosen in a combo (degraded gauges are marked in it, and
their degraded points on the curve).
"""

from __future__ import annotations

import numpy as np

from ..i18n import tr, tr_noop
from ..i18n.retranslate import say_english

__all__ = ["deformed_hint", "fill_gauges", "chosen_gauge", "translate_axes", "probe_messages",
           "ENGINE_TEXTS", "said"]

DEGRADED = 1
STATUS = {0: tr_noop("ok"), 1: tr_noop("degraded"), 2: tr_noop("missing")}
#: the probe table's group of the testing machine's columns (load_N, stress_MPa)
LOAD_GROUP = tr_noop("load")
#: the English texts of the engine's probes (engine/probes, engine/viz/probe_page),
#: word for word with their values as placeholders: the dock shows them translated
#: (tests/plugin/test_probe_text.py holds them to the engine's own output)
ENGINE_TEXTS = (
    # plots
    tr_noop("frame"), tr_noop("time [{unit}]"), tr_noop("dimensionless"),
    tr_noop("engineering stress [MPa]"), tr_noop("stress-strain"), tr_noop("degraded"),
    tr_noop("{gauge} (engineering strain)"),
    tr_noop("stress-strain: needs load data and a line gauge"),
    # reasons of a missing or degraded value (sampling, measure, table, load)
    tr_noop("({x}, {y}) is outside the image ({cols} x {rows} px)"),
    tr_noop("({x}, {y}) is outside the ROI (crack, hole or background): move it onto the "
            "material"),
    tr_noop("extrapolated {distance} px from the nearest trusted node"),
    tr_noop("the {n} trusted nodes near the point lie on one line: no plane through them"),
    tr_noop("no node within {radius} node spacings that the point sees inside the ROI "
            "(outside the measured field)"),
    tr_noop("the point left the field of view (its nodes' deformed subsets leave the image)"),
    tr_noop("too few trusted nodes around the point ({good} of {near}; untrusted: "
            "{reasons})"),
    tr_noop("only {n} node(s) within {radius} node spacings: the point is outside the "
            "measured field"),
    tr_noop("too few nodes with a value around the point ({good} of {near}; the field is "
            "not defined there, e.g. strain at the ROI edge)"),
    tr_noop("start point: {reason}"), tr_noop("end point: {reason}"),
    tr_noop("a crack or hole (outside the ROI) lies between the gauge points: the strain "
            "includes its opening"),
    tr_noop("no node inside the area (smaller than the node spacing?)"),
    tr_noop("none of the {n} nodes in the area is trusted"),
    tr_noop("only {trusted} of the {n} nodes in the area are trusted"),
    tr_noop("not computable"),
    tr_noop("{what} {value}{unit} is outside the load record ({low}{unit} to {high}{unit}); "
            "no extrapolation"),
    tr_noop("{reason} [{columns}]"),
    tr_noop("{n} load samples from {file} ({columns}; load read in {unit})"),
)


def said(text: str) -> str:
    """An English text of the engine in the user's language (names and numbers
    in it stay; a text that is no message stays as it is)."""
    return say_english(text) if text else text


def _gauges(table) -> list[str]:
    """The strain columns of the line gauges (``line1_strain``, ...)."""
    return [n for n in table.columns if n.startswith("line") and n.endswith("_strain")
            and not n.endswith("_true_strain")]


def fill_gauges(combo, table) -> None:
    """Fill ``combo`` with the gauges of ``table`` (a degraded one says so),
    keeping the user's choice when that gauge still exists."""
    keep = combo.currentData()
    combo.blockSignals(True)
    combo.clear()
    for name in _gauges(table) if table is not None else []:
        gauge = name.split("_", 1)[0]
        bad = (np.asarray(table.columns[name].status) == DEGRADED).any()
        combo.addItem(tr("{gauge} (degraded)").format(gauge=gauge) if bad else gauge, name)
    index = combo.findData(keep)
    combo.setCurrentIndex(max(index, 0))
    combo.setEnabled(combo.count() > 1)  # a choice only between gauges
    combo.blockSignals(False)


def chosen_gauge(combo, table) -> str | None:
    """The strain column of the gauge chosen in ``combo`` (the first one by default)."""
    name = combo.currentData()
    if table is not None and name in table.columns:
        return name
    gauges = _gauges(table) if table is not None else []
    return gauges[0] if gauges else None


def translate_axes(axes) -> None:
    """Put the engine's English axis labels, titles, texts and legend entries of
    ``axes`` in the user's language."""
    for ax in axes:
        ax.set_xlabel(said(ax.get_xlabel()))
        ax.set_ylabel(said(ax.get_ylabel()))
        ax.set_title(said(ax.get_title()), fontsize=ax.title.get_fontsize())
        legend = ax.get_legend()
        for text in [*ax.texts, *(legend.get_texts() if legend is not None else [])]:
            text.set_text(said(text.get_text()))


def probe_messages(table, max_frames: int = 5) -> list[str]:
    """One translated line per probe that is not ok at every frame: its worst
    status, the frames and the first reason (the reason as the engine says it)."""
    out = []
    for group in table.groups():
        status, reasons = table.group_status(group)
        bad = np.nonzero(status > 0)[0]
        if not bad.size:
            continue
        frames = ", ".join(str(int(table.frames[i])) for i in bad[:max_frames])
        frames += " ..." if bad.size > max_frames else ""
        why = next((reasons[i] for i in bad if reasons[i]), "")
        out.append(tr("{probe}: {status} at frame(s) {frames}: {why}").format(
            probe=tr(LOAD_GROUP) if group == "load" else group,
            status=tr(STATUS[int(status.max())]), frames=frames, why=said(why)))
    return out


def deformed_hint(view) -> list[str]:
    """A line when the maps show the deformed configuration: probes stay where
    they were drawn, in reference coordinates (issue 24, trap 15)."""
    meta = getattr(view.layer, "metadata", {}).get("napari_aldic", {})
    if not meta.get("deformed"):
        return []
    return [tr("Probes are read in the reference configuration; the maps show the deformed "
               "one: a probe measures the material that was under it at frame 0.")]
