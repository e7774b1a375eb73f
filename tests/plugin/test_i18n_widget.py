"""The widget in other languages (issue 17).

* the pseudo-locale ``qps``: the whole dock widget and the probes dock are built and
  every visible text (labels, buttons, section titles, group boxes, tabs, combo items,
  tooltips, placeholders, window titles) must have passed through ``tr``;
* each of the eight languages at 1280 x 720: a screenshot (in the test's folder), and
  no label or button whose text is cut off;
* the language selector: native names, remembered, applied to the next widget;
* a font for Chinese, Japanese and Korean is installed (CI: fonts-noto-cjk).
"""

from __future__ import annotations

import re

import napari  # noqa: F401  (testing extra: missing, these tests fail, not skip)
import numpy as np
import pytest
import pytestqt  # noqa: F401

from napari_aldic import i18n
from napari_aldic._qt import DICWidget
from napari_aldic._qt.language import SYSTEM
from napari_aldic._qt.plot_dock import ProbePlotDock
from napari_aldic._qt.prefs import read_language
from napari_aldic._qt.units import LENGTH_UNITS, TIME_UNITS
from napari_aldic.engine.probes import LINE_QUANTITIES
from napari_aldic.i18n.pseudo import CLOSE, OPEN

# needs a display: without one these tests are skipped (tests/plugin/conftest.py)
pytestmark = pytest.mark.gui

#: words that may be shown untranslated: names, units, symbols, field names, the layer
#: names of the test's own data, the languages' own names in the selector
ALLOWED_WORDS = {
    "napari-aldic", "AL-DIC", "DIC", "ZNCC", "px", "µm", "mm", "s", "u", "v", "|u|", "exx",
    "eyy", "exy", "e1", "e2", "English", "Deutsch", "Français", "Español",
    # the test's layers (user data) and the probe dock's layer names found by name
    "speckle", "ROI", "hole", "seeds", "probes", "probe points",
    # probe quantities and fields: the engine's column names, shown as they are
    *LINE_QUANTITIES, "magnitude", "von_mises", "von Mises",
    # unit symbols of the Units panel ("frame" is a word: it is translated)
    *(set(LENGTH_UNITS) | set(TIME_UNITS)) - {"frame"},
}
_TAGS = re.compile(r"<[^<>]*>|&[#\w]+;")
_PSEUDO = re.compile(re.escape(OPEN) + r".*?" + re.escape(CLOSE), re.S)


def _untranslated(text: str) -> str | None:
    """The part of ``text`` that did not pass through ``tr`` under ``qps``, or None."""
    rest = _PSEUDO.sub(" ", _TAGS.sub(" ", text or ""))
    for name in sorted(ALLOWED_WORDS, key=len, reverse=True):  # multi-word names first
        rest = re.sub(rf"(?<![\w-]){re.escape(name)}(?![\w-])", " ", rest)
    words = re.findall(r"[A-Za-z][A-Za-z_]+", rest)
    return rest.strip() if words else None


def _texts(root):
    """``(where, text)`` of every visible text of ``root`` and its children."""
    from qtpy.QtWidgets import (
        QAbstractButton,
        QComboBox,
        QGroupBox,
        QLabel,
        QLineEdit,
        QPlainTextEdit,
        QTabWidget,
        QTextEdit,
        QWidget,
    )

    for w in [root, *root.findChildren(QWidget)]:
        kind = type(w).__name__
        if w.toolTip():
            yield f"{kind} tooltip", w.toolTip()
        if w.isWindow() and w.windowTitle():
            yield f"{kind} window title", w.windowTitle()
        if isinstance(w, QLabel):
            yield kind, w.text()
        elif isinstance(w, QAbstractButton):
            yield kind, w.text().replace("&", "")
        elif isinstance(w, QGroupBox):
            yield kind, w.title()
        elif isinstance(w, QLineEdit):
            yield f"{kind} placeholder", w.placeholderText()
        elif isinstance(w, QTabWidget):
            for i in range(w.count()):
                yield f"{kind} tab", w.tabText(i)
        elif isinstance(w, (QTextEdit, QPlainTextEdit)):  # the log: line by line
            for line in w.toPlainText().splitlines():
                yield f"{kind} line", line
        if isinstance(w, QComboBox):
            for i in range(w.count()):
                yield f"{kind} item", w.itemText(i)


@pytest.fixture
def language(monkeypatch):
    """``language(code)``: the widgets made next speak ``code``; English afterwards."""
    def use(code: str) -> None:
        monkeypatch.setenv(i18n.ENV_VAR, code)

    yield use
    i18n.set_language("en")


def _widget(viewer, qtbot):
    viewer.add_image(np.zeros((3, 96, 96), np.uint8), name="speckle")
    w = DICWidget(viewer)
    viewer.window.add_dock_widget(w, name="DIC (AL-DIC)", area="right")
    qtbot.wait(50)
    return w


def test_pseudo_locale_finds_no_untranslated_text(make_napari_viewer, qtbot, language,
                                                  small_analysis):
    language("qps")
    viewer = make_napari_viewer()
    w = _widget(viewer, qtbot)
    assert i18n.current_language() == "qps"
    w.show_analysis(small_analysis)  # the legend, the log and the status lines too
    dock = ProbePlotDock(viewer)
    qtbot.addWidget(dock)
    found = list(_texts(w.native)) + list(_texts(dock))
    assert len(found) > 100  # the walk sees the widget
    assert sum(OPEN in text for _, text in found) > 80
    bad = sorted({f"{where}: {text!r}" for where, text in found if _untranslated(text)})
    assert not bad, f"{len(bad)} texts not passed through tr():\n  " + "\n  ".join(bad)


def test_the_check_sees_an_untranslated_label():
    """The pseudo-locale test would fail on plain English and pass on names/units."""
    assert _untranslated("Subset (px)") is not None
    assert _untranslated("⟦Šûbšéç (px)⟧") is None
    assert _untranslated("<b>⟦Àñàlýšîš⟧</b> 3/4 · 0:05") is None
    assert _untranslated("DIC u [px]") is None
    assert _untranslated("⟦Fîlé⟧: frame 3") is not None


def _folded(w, root) -> bool:
    """Whether ``w`` lies in a folded section (a collapsed content has no height)."""
    while w is not None and w is not root:
        if w.width() <= 1 or w.height() <= 1:
            return True
        w = w.parentWidget()
    return False


def _cut_off(root) -> list[str]:
    """Visible labels and buttons whose text does not fit their width."""
    from qtpy.QtWidgets import QAbstractButton, QLabel

    bad = []
    for w in root.findChildren((QLabel, QAbstractButton)):
        if not w.isVisible() or _folded(w, root):
            continue
        if isinstance(w, QLabel):
            if w.wordWrap() or w.textFormat() == 1 or "<" in w.text():  # wraps / rich text
                need = w.heightForWidth(w.width()) if w.wordWrap() else -1
                if need > w.height() + 2:
                    bad.append(f"{w.text()[:60]!r}: needs {need} px height, has {w.height()}")
                continue
            room = w.contentsRect().width()
            need = max((w.fontMetrics().horizontalAdvance(line)
                        for line in w.text().splitlines() or [""]), default=0)
        else:
            room, need = w.width(), w.minimumSizeHint().width()
        if need > room + 1:
            bad.append(f"{type(w).__name__} {w.text()[:60]!r}: needs {need} px, has {room}")
    return bad


@pytest.mark.parametrize("code", sorted(i18n.LANGUAGES))
def test_widget_in_each_language_at_1280x720(make_napari_viewer, qtbot, tmp_path, language,
                                             save_screenshot, code):
    language(code)
    viewer = make_napari_viewer(show=True)
    viewer.window.resize(1280, 720)
    w = _widget(viewer, qtbot)
    assert i18n.current_language() == code
    for title in ("Project and parameters", "3. Strain"):
        w.sections[title].expand(animate=False)
    qtbot.wait(200)
    window = viewer.window._qt_window
    assert (window.width(), window.height()) == (1280, 720)
    area = w.scroll_area
    assert area.widget().width() <= area.viewport().width()  # nothing cut at the right
    bad = _cut_off(w.native)
    save_screenshot(viewer, tmp_path / f"widget_{code}_1280x720_top.png")
    dock = ProbePlotDock(viewer)  # the probes dock in a window of its own width, 700 px high
    qtbot.addWidget(dock)
    dock.resize(dock.sizeHint().width(), 700)
    dock.show()
    dock.recompute()  # its status line and the plot's text
    dock.canvas.draw()
    qtbot.wait(100)
    bad += _cut_off(dock)
    dock.grab().save(str(tmp_path / f"probes_{code}.png"))
    area.ensureWidgetVisible(w.language.native)  # the selector in the screenshot
    qtbot.wait(100)
    shot = tmp_path / f"widget_{code}_1280x720.png"
    save_screenshot(viewer, shot)
    assert 10_000 < shot.stat().st_size < 800_000
    assert not bad, f"{code}: text cut off (screenshot {shot}):\n  " + "\n  ".join(bad)


def test_the_check_sees_a_cut_off_label_and_button(qtbot):
    from qtpy.QtWidgets import QLabel, QPushButton, QVBoxLayout, QWidget

    root = QWidget()
    qtbot.addWidget(root)
    layout = QVBoxLayout(root)
    label, button = QLabel("Verschiebungsvektoren anzeigen"), QPushButton("Parameter laden…")
    fits = QLabel("ok")
    for w in (label, button, fits):
        layout.addWidget(w)
    root.show()
    root.resize(400, 200)
    qtbot.wait(50)
    assert _cut_off(root) == []
    label.setFixedWidth(40)
    button.setFixedWidth(30)
    qtbot.wait(50)
    bad = _cut_off(root)
    assert len(bad) == 2 and "Verschiebung" in bad[0] and "Parameter" in bad[1]


def test_language_selector_is_remembered(make_napari_viewer, qtbot, monkeypatch):
    monkeypatch.delenv(i18n.ENV_VAR, raising=False)
    for var in ("LANGUAGE", "LC_ALL", "LC_MESSAGES"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("LANG", "fr_CA.UTF-8")
    viewer = make_napari_viewer()
    try:
        w = _widget(viewer, qtbot)
        assert i18n.current_language() == "fr"  # the environment, regional variant -> base
        combo = w.language.combo
        assert combo.value == SYSTEM
        names = [combo.native.itemText(i) for i in range(combo.native.count())]
        assert names[1:] == list(i18n.available_languages().values())
        combo.value = "ja"
        assert read_language() == "ja"
        w2 = DICWidget(viewer)  # the next widget speaks the chosen language
        assert i18n.current_language() == "ja" and w2.language.combo.value == "ja"
        w2.language.combo.value = SYSTEM  # back to the system's language
        assert read_language() is None
        DICWidget(viewer)
        assert i18n.current_language() == "fr"
    finally:
        i18n.set_language("en")


def test_qt_locale_is_the_fallback_without_environment(qapp, monkeypatch):
    """No LANGUAGE/LC_*/LANG (Windows, macOS): Qt's QLocale default decides."""
    from qtpy.QtCore import QLocale

    from napari_aldic._qt.language import ui_language

    for var in (i18n.ENV_VAR, "LANGUAGE", "LC_ALL", "LC_MESSAGES", "LANG"):
        monkeypatch.delenv(var, raising=False)
    before = QLocale()
    try:
        QLocale.setDefault(QLocale("zh_HK"))
        assert ui_language() == "zh_TW"
        QLocale.setDefault(QLocale("pt_BR"))
        assert ui_language() == "en"
        monkeypatch.setenv("LANG", "es_MX.UTF-8")  # the environment comes first
        assert ui_language() == "es"
    finally:
        QLocale.setDefault(before)


def test_fonts_for_chinese_japanese_korean(qapp):
    from qtpy.QtGui import QFontDatabase

    ws = QFontDatabase.WritingSystem
    missing = [name for name in ("SimplifiedChinese", "TraditionalChinese", "Japanese",
                                 "Korean") if not QFontDatabase.families(getattr(ws, name))]
    assert not missing, (f"no font for {missing}: install a CJK font (Debian: fonts-noto-cjk, "
                         "see docs/languages.md)")
    # matplotlib (the probes dock's plot) is given the Noto CJK font of each language
    from napari_aldic._qt.language import plot_fonts

    try:
        for code in ("zh_CN", "zh_TW", "ja", "ko"):
            i18n.set_language(code)
            assert "CJK" in plot_fonts().get("font.family", ["", ""])[1], code
        i18n.set_language("de")
        assert plot_fonts() == {}
    finally:
        i18n.set_language("en")


# ------------------------------------------------------------------ a live change (issue 24)
def test_a_live_change_to_the_pseudo_locale_leaves_no_text_behind(make_napari_viewer, qtbot,
                                                                   language, small_analysis):
    """Made in English, then switched while open: every text is said anew (the log
    keeps the lines it wrote), as if the docks had been made in the new language."""
    from napari_aldic._qt.language import switch_language

    language("en")
    viewer = make_napari_viewer()
    w = _widget(viewer, qtbot)
    w.show_analysis(small_analysis)
    dock = ProbePlotDock(viewer)
    qtbot.addWidget(dock)
    dock.recompute()
    english = list(_texts(w.native)) + list(_texts(dock))
    assert sum(bool(_untranslated(t)) for _, t in english) > 100  # English before
    switch_language("qps")
    qtbot.wait(300)  # the probe dock measures again after its timer
    found = [(where, text) for where, text in list(_texts(w.native)) + list(_texts(dock))
             if where != "QTextEdit line"]
    assert sum(OPEN in text for _, text in found) > 80
    bad = sorted({f"{where}: {text!r}" for where, text in found if _untranslated(text)})
    assert not bad, f"{len(bad)} texts not said anew:\n  " + "\n  ".join(bad)


@pytest.mark.parametrize("code", ["de", "ja"])
def test_a_live_change_fits_like_a_dock_made_in_the_language(make_napari_viewer, qtbot,
                                                              tmp_path, language,
                                                              save_screenshot, code):
    """English at 1280 x 720, then the language changed while open: the labels'
    column takes the new widths, nothing is cut off (screenshot in the test folder)."""
    from napari_aldic._qt.language import switch_language

    language("en")
    viewer = make_napari_viewer(show=True)
    viewer.window.resize(1280, 720)
    w = _widget(viewer, qtbot)
    for title in ("Project and parameters", "3. Strain"):
        w.sections[title].expand(animate=False)
    switch_language(code)
    qtbot.wait(200)
    shot = tmp_path / f"widget_live_{code}_1280x720.png"
    save_screenshot(viewer, shot)
    assert w.sections["3. Strain"].text() == i18n.tr("3. Strain") != "3. Strain"
    area = w.scroll_area
    assert area.widget().width() <= area.viewport().width()  # nothing cut at the right
    bad = _cut_off(w.native)
    assert not bad, f"{code}: text cut off (screenshot {shot}):\n  " + "\n  ".join(bad)
