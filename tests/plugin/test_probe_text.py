"""The probes dock in every language (issue 24, trap 13): the engine's English
reasons (a probe outside the image, outside the ROI, an empty area, a frame beyond
the load record ...), its plot labels and the load file's description are shown
translated; the German Export section fits at 1280 x 720. Failed before: the
reasons and part of the plot text stayed English in de/ja (and the others)."""

from __future__ import annotations

import re
import string

import numpy as np
import pytest

from napari_aldic import i18n
from napari_aldic._qt.gauges import ENGINE_TEXTS, probe_messages, said

TRANSLATED = sorted(set(i18n.LANGUAGES) - {"en"})
#: values for the placeholders of the engine's texts
SAMPLE = {"x": "300.0", "y": "12.5", "cols": "192", "rows": "192", "distance": "3.4", "n": "4",
          "radius": "2.5", "good": "2", "near": "6", "trusted": "3", "what": "frame",
          "value": "7", "unit": "", "low": "0", "high": "5", "columns": "line1_u, line1_v",
          "file": "machine.csv", "gauge": "line1_strain",
          "reason": "the point left the field of view (its nodes' deformed subsets leave "
                    "the image)",
          "reasons": "subset component too small (mask): 3"}
#: English words that must not be left in a translated reason ("image", "point" are French too)
ENGLISH = re.compile(r"\b(outside|image|trusted|nodes?|point|field|area|between|extrapolated|"
                     r"start|end|load|record|needs|too few|computable|samples|frame)\b")
SAME_WORD = {"fr": {"image", "point"}}
#: what the load file's description quotes from the file: its column names
QUOTED = re.compile(r"\w+ = '[^']*'")


def _english(text: str, lang: str) -> list[str]:
    text = QUOTED.sub("", text.replace("machine.csv", "").replace("line1_u", ""))
    return [w for w in ENGLISH.findall(text) if w not in SAME_WORD.get(lang, set())]


def _filled(template: str) -> str:
    names = {f for _, f, _, _ in string.Formatter().parse(template) if f}
    return template.format(**{k: SAMPLE[k] for k in names})


@pytest.fixture
def language():
    yield i18n.set_language
    i18n.set_language("en")


@pytest.mark.parametrize("lang", TRANSLATED)
def test_trap13_every_engine_probe_text_is_translated(lang, language):
    language(lang)
    for template in ENGINE_TEXTS:
        english = _filled(template)
        text = said(english)
        if template == "{reason} [{columns}]":  # the columns' names stay
            assert text.endswith(" [line1_u, line1_v]") and "field of view" not in text
            continue
        assert text != english, (lang, english)
        assert not _english(text, lang), (lang, text)
    # names and numbers stay: a point's coordinates, the image size
    assert "300.0" in said(_filled(ENGINE_TEXTS[8])) and "192" in said(_filled(ENGINE_TEXTS[8]))


def _table(analysis, tmp_path):
    """Probes that the engine cannot measure everywhere, with a short load record."""
    from napari_aldic._qt.probes import ResultView, measure_analysis
    from napari_aldic.engine import Units
    from napari_aldic.engine.probes import (
        AreaProbe,
        LineProbe,
        PointProbe,
        ProbeSet,
        attach_load,
        read_load_csv,
    )

    probes = ProbeSet()
    probes.points += [PointProbe(300.0, 12.0), PointProbe(10.0, 100.0)]  # image, ROI
    probes.lines.append(LineProbe(60.0, 60.0, 250.0, 60.0))  # its end outside the image
    probes.areas.append(AreaProbe.rectangle(60.2, 60.2, 60.6, 60.6))  # no node inside
    view = ResultView(analysis, np.ones(2), np.zeros(2), None, 0.0, Units(), None)
    table = measure_analysis(view, probes)
    load = tmp_path / "machine.csv"
    load.write_text("Frame;Force\n(-);(kN)\n0;0\n1;1.2\n", encoding="utf-8")
    record = read_load_csv(load)
    attach_load(table, record, area_mm2=12.0, sync="frame")  # frame 2: beyond the record
    return table, record


@pytest.mark.parametrize("lang", ["de", "ja"])
def test_trap13_the_engines_own_reasons_are_translated(lang, language, small_analysis,
                                                       tmp_path):
    table, record = _table(small_analysis, tmp_path)
    reasons = {r for c in table.columns.values() for r in c.reasons if r}
    kinds = ("outside the image", "outside the ROI", "end point: ", "no node inside the area",
             "outside the load record")
    assert all(any(k in r for r in reasons) for k in kinds), reasons
    english_lines = probe_messages(table)
    language(lang)
    for reason in [*reasons, record.describe()]:
        text = said(reason)
        assert text != reason and not _english(text, lang), text
    lines = probe_messages(table)
    assert len(lines) == len(english_lines) >= 4
    for line in lines:  # the dock's status: probe names stay, the words are translated
        assert not _english(re.sub(r"\[[^]]*\]|\w+\d\b|\w+\d_\w+", "", line), lang), line


@pytest.mark.gui
@pytest.mark.parametrize("lang", ["de", "ja"])
def test_trap13_the_probes_dock_speaks_the_language(make_napari_viewer_proxy, qtbot, tmp_path,
                                                    small_analysis, monkeypatch, lang):
    from napari_aldic._layers import Display
    from napari_aldic._qt.plot_dock import ProbePlotDock
    from napari_aldic._qt.results import ResultLayers

    monkeypatch.setenv(i18n.ENV_VAR, lang)
    try:
        viewer = make_napari_viewer_proxy()
        image = viewer.add_image(np.zeros((3, 192, 192), np.float32), name="speckle")
        results = ResultLayers(viewer)
        results.analysis, results.image = small_analysis, image
        results.show(Display(), image)
        dock = ProbePlotDock(viewer)
        qtbot.addWidget(dock)
        dock.add_probe_layers()
        dock.shapes_layer.add_lines(np.array([[60.0, 60.0], [60.0, 250.0]]))  # ends outside
        dock.points_layer.add([12.0, 300.0])  # outside the image
        load = tmp_path / "machine.csv"
        load.write_text("Frame;Force\n(-);(kN)\n0;0\n1;1.2\n", encoding="utf-8")
        assert dock.load_csv(load, area_mm2=12.0)
        dock.recompute()
        status = dock.status_label.text()
        assert said("(300.0, 12.0) is outside the image (192 x 192 px)") in status
        assert "outside" not in status and "end point" not in status, status
        assert "load samples" not in dock.load_label.text()
        lines = dock.axes["lines"]
        assert lines.get_xlabel() == i18n.tr("frame") != "frame"
        assert lines.get_ylabel() == i18n.tr("dimensionless") != "dimensionless"
        stress = dock.axes["stress"]
        for text in (stress.get_xlabel(), stress.get_ylabel(), stress.get_title()):
            assert not re.search(r"engineering|stress|strain\)", text), text
        dock.canvas.draw()
        dock.grab().save(str(tmp_path / f"probes_{lang}.png"))
    finally:
        i18n.set_language("en")


@pytest.mark.gui
def test_trap13_the_german_export_section_fits(make_napari_viewer, qtbot, tmp_path,
                                               monkeypatch, save_screenshot, small_analysis):
    """Every label, button, choice and the note of the Export section fit their
    width in German at 1280 x 720 (a screenshot is kept)."""
    from qtpy.QtWidgets import QAbstractButton, QComboBox, QLabel

    from napari_aldic._qt import DICWidget
    from napari_aldic._qt.export import FORMATS

    monkeypatch.setenv(i18n.ENV_VAR, "de")
    try:
        viewer = make_napari_viewer(show=True)
        viewer.window.resize(1280, 720)
        viewer.add_image(np.zeros((3, 192, 192), np.uint8), name="speckle")
        w = DICWidget(viewer)
        viewer.window.add_dock_widget(w, name="DIC (AL-DIC)", area="right")
        w.show_analysis(small_analysis)
        for title, box in w.sections.items():
            box.expand(animate=False) if title == "6. Export" else box.collapse(animate=False)
        qtbot.wait(300)
        section = w.exports.native
        w.scroll_area.ensureWidgetVisible(section)
        qtbot.wait(100)
        bad = []
        for label in section.findChildren(QLabel):
            if not label.isVisible() or not label.text():
                continue
            if label.wordWrap():
                if label.heightForWidth(label.width()) > label.height() + 2:
                    bad.append(label.text())
            elif label.fontMetrics().horizontalAdvance(label.text()) > \
                    label.contentsRect().width() + 1:
                bad.append(label.text())
        for button in section.findChildren(QAbstractButton):
            if button.isVisible() and button.minimumSizeHint().width() > button.width() + 1:
                bad.append(button.text())
        for combo in section.findChildren(QComboBox):
            room = combo.width() - 28  # the arrow and the frame
            for i in range(combo.count()):
                if combo.fontMetrics().horizontalAdvance(combo.itemText(i)) > room:
                    bad.append(combo.itemText(i))
        formats = w.exports.format.native
        assert formats.count() == len(FORMATS)
        for i in range(formats.count()):  # the whole text also on hover
            formats.setCurrentIndex(i)
            assert formats.toolTip().startswith(formats.currentText())
        shot = tmp_path / "export_de_1280x720.png"
        save_screenshot(viewer, shot)
        assert not bad, f"cut off in German (see {shot}): {bad}"
    finally:
        i18n.set_language("en")
