"""The probe plot dock's gauge choice and its translated plot text.

The engine draws the probe curves in English (it never imports the catalogues);
the dock passes its axes here to put the labels in the user's language, and
chooses the gauge of the stress-strain curve from a combo (degraded gauges are
marked in it, and their degraded points on the curve).
"""

from __future__ import annotations

import numpy as np

from ..i18n import tr, tr_noop

__all__ = ["deformed_hint", "fill_gauges", "chosen_gauge", "translate_axes", "probe_messages"]

DEGRADED = 1
STATUS = {0: tr_noop("ok"), 1: tr_noop("degraded"), 2: tr_noop("missing")}
#: the engine's English plot text -> its message id (translated when shown)
_TEXTS = {"frame": tr_noop("frame"), "engineering stress [MPa]":
          tr_noop("engineering stress [MPa]"), "stress-strain": tr_noop("stress-strain"),
          "dimensionless": tr_noop("dimensionless"), "degraded": tr_noop("degraded")}


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


def _said(text: str) -> str:
    if text in _TEXTS:
        return tr(_TEXTS[text])
    if text.endswith(" (engineering strain)"):
        return tr("{gauge} (engineering strain)").format(gauge=text.split(" ", 1)[0])
    return text


def translate_axes(axes) -> None:
    """Put the engine's English axis labels, titles and legend entries of
    ``axes`` in the user's language."""
    for ax in axes:
        ax.set_xlabel(_said(ax.get_xlabel()))
        ax.set_ylabel(_said(ax.get_ylabel()))
        ax.set_title(_said(ax.get_title()), fontsize=ax.title.get_fontsize())
        legend = ax.get_legend()
        for text in legend.get_texts() if legend is not None else []:
            text.set_text(_said(text.get_text()))


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
            probe=group, status=tr(STATUS[int(status.max())]), frames=frames, why=why))
    return out


def deformed_hint(view) -> list[str]:
    """A line when the maps show the deformed configuration: probes stay where
    they were drawn, in reference coordinates (issue 24, trap 15)."""
    meta = getattr(view.layer, "metadata", {}).get("napari_aldic", {})
    if not meta.get("deformed"):
        return []
    return [tr("Probes are read in the reference configuration; the maps show the deformed "
               "one: a probe measures the material that was under it at frame 0.")]
