"""The widget's language, its selector, and a change of language in open docks.

The order (docs/languages.md): ``NAPARI_ALDIC_LANGUAGE``; the language chosen in
the selector (remembered in the configuration folder, :mod:`.prefs`); the
environment as gettext reads it (LANGUAGE, LC_ALL, LC_MESSAGES, LANG); Qt's
``QLocale()`` (the system's language on Windows and macOS); English.

A new choice in the selector applies at once (issue 24, trap 5): every open dock
that follows the language (:func:`follow_language`) has its texts said in the new
language (:func:`retranslate_tree`: labels, buttons, section titles, tooltips,
combo items, placeholders) and refreshes what it computes (status lines, plots).
Nothing is rebuilt, so every control keeps its value and the analysis stays.
"""

from __future__ import annotations

import os
import weakref
from collections.abc import Callable

from magicgui.widgets import ComboBox, Container, Label

from ..i18n import (
    ENV_VAR,
    available_languages,
    current_language,
    language_from_environment,
    resolve_language,
    set_language,
    tr,
)
from ..i18n.retranslate import Retranslator
from .prefs import read_language, write_language

__all__ = ["ui_language", "apply_ui_language", "LanguageSelector", "SYSTEM", "combo_of",
           "plot_fonts", "switch_language", "follow_language", "retranslate_tree", "KEEP_TEXT"]

#: the selector's value for "follow the system"
SYSTEM = "system"
#: a widget property: its texts are data (layer or column names), never retranslated
KEEP_TEXT = "napari_aldic_keep_text"
#: ``(weak reference to the owner, callback)`` of the docks that follow the language
_FOLLOWERS: list[tuple[weakref.ref, Callable]] = []
#: the Noto CJK family (fonts-noto-cjk) that matplotlib needs for each CJK language
_CJK_FAMILIES = {"zh_CN": "SC", "zh_TW": "TC", "ja": "JP", "ko": "KR"}


def _qt_locale_name() -> str | None:
    try:
        from qtpy.QtCore import QLocale

        return QLocale().name()
    except Exception:  # pragma: no cover - no Qt binding
        return None


def ui_language() -> str:
    """The language the widget should speak now (see the module's order)."""
    override = resolve_language(os.environ.get(ENV_VAR, ""))
    if override is not None:
        return override
    chosen = resolve_language(read_language())
    if chosen is not None:
        return chosen
    return language_from_environment(fallback=_qt_locale_name())


def apply_ui_language() -> str:
    """Make :func:`ui_language` the language of the process (the open docks follow
    when it changes); return it."""
    return switch_language(ui_language())


def switch_language(code: str) -> str:
    """Speak ``code`` from now on; every dock that follows the language is said
    in it at once. Returns the language in use."""
    old = current_language()
    new = set_language(code)
    if new != old:
        rt = Retranslator(old, new)
        for ref, callback in list(_FOLLOWERS):
            owner = ref()
            try:
                if owner is not None:
                    callback(owner, rt)
            except RuntimeError:  # its Qt object is gone
                owner = None
            except Exception as exc:  # one dock never keeps the others from following
                from napari.utils.notifications import show_error

                show_error(tr("napari-aldic: could not change the language of a dock: "
                              "{exc}").format(exc=exc))
            if owner is None:
                _forget(ref)
    return new


def _forget(ref) -> None:
    _FOLLOWERS[:] = [(r, cb) for r, cb in _FOLLOWERS if r is not ref]


def follow_language(owner, callback: Callable | None = None) -> None:
    """Say ``owner`` (a ``QWidget``, or a magicgui widget) in each new language
    until it is destroyed: ``callback(owner, retranslator)``, by default
    :func:`retranslate_tree` of it. Only a weak reference to ``owner`` is kept."""
    ref = weakref.ref(owner)
    _FOLLOWERS.append((ref, callback or (lambda o, rt: retranslate_tree(
        getattr(o, "native", o), rt))))
    getattr(owner, "native", owner).destroyed.connect(lambda *_: _forget(ref))


def _plain(value) -> bool:
    return value is None or isinstance(value, (str, int, float, bool))


def _put(rt: Retranslator, text: str, put) -> None:
    new = rt.text(text)
    if new is not None and new != text:
        put(new)


def _combo(combo, rt: Retranslator) -> None:
    """The items of a combo box that are messages (values are kept: magicgui's
    stored choices are said anew too, so that a reset of its choices keeps them)."""
    magic = getattr(combo, "_magic_widget", None)
    pairs = getattr(magic, "_default_choices", None)
    pairs = pairs if isinstance(pairs, (list, tuple)) and all(
        isinstance(p, tuple) and len(p) == 2 for p in pairs) else None
    for i in range(combo.count()):
        data = combo.itemData(i)
        # plain combos: items with a value (text = data: names); magicgui: its pairs,
        # or only its empty choice (the others are layers or values shown as they are)
        if (magic is None and data is not None) or (magic is not None and _plain(data) and (
                pairs is not None or data is None)):
            _put(rt, combo.itemText(i), lambda t, i=i: combo.setItemText(i, t))
    if pairs is not None:
        magic._default_choices = [((rt.text(t) or t) if _plain(v) else t, v) for t, v in pairs]
    if magic is not None and "null_string" in vars(magic):
        _put(rt, magic.null_string, lambda t: setattr(magic, "null_string", t))


def _texts_of(w):
    """``(get, set)`` of the texts a widget shows itself."""
    from qtpy.QtWidgets import (
        QAbstractButton,
        QAbstractSpinBox,
        QGroupBox,
        QLabel,
        QLineEdit,
        QPlainTextEdit,
        QProgressBar,
        QTabWidget,
        QTextEdit,
    )

    yield w.toolTip, w.setToolTip
    if w.isWindow():
        yield w.windowTitle, w.setWindowTitle
    if isinstance(w, (QLabel, QAbstractButton)):
        yield w.text, w.setText
    elif isinstance(w, QGroupBox):
        yield w.title, w.setTitle
    elif isinstance(w, (QLineEdit, QTextEdit, QPlainTextEdit)):
        yield w.placeholderText, w.setPlaceholderText
    elif isinstance(w, QAbstractSpinBox):
        yield w.specialValueText, w.setSpecialValueText
        if hasattr(w, "suffix"):
            yield w.suffix, w.setSuffix
    elif isinstance(w, QProgressBar):
        yield w.format, w.setFormat
    elif isinstance(w, QTabWidget):
        for i in range(w.count()):
            yield (lambda i=i: w.tabText(i)), (lambda t, i=i: w.setTabText(i, t))


def retranslate_tree(root, rt: Retranslator) -> None:
    """Say every text of ``root`` and its children in the new language: labels,
    buttons, group boxes, tabs, tooltips, placeholders, combo items, and the
    labels magicgui keeps. Values (spin boxes, text typed, chosen items) stay,
    so do texts that are no message (layer names, numbers) and a log's lines."""
    from qtpy.QtWidgets import QComboBox, QWidget

    for w in [root, *root.findChildren(QWidget)]:
        if w.property(KEEP_TEXT):
            continue
        for get, put in _texts_of(w):
            _put(rt, get(), put)
        if isinstance(w, QComboBox):
            _combo(w, rt)
        magic = getattr(w, "_magic_widget", None)
        if isinstance(getattr(magic, "_label", None), str):
            _put(rt, magic._label, lambda t, m=magic: setattr(m, "label", t))
    from qtpy.QtCore import QTimer

    QTimer.singleShot(0, lambda: _fit_dock(root))  # once the new texts are laid out


def _fit_dock(root) -> None:
    """Widen the napari dock holding ``root`` when its new texts need more room
    (a dock keeps the width it was given; a longer language would be cut off)."""
    from qtpy.QtCore import QCoreApplication, QEvent, Qt
    from qtpy.QtWidgets import QDockWidget, QMainWindow

    try:
        QCoreApplication.sendPostedEvents(None, QEvent.Type.LayoutRequest)  # sizes anew
        dock = root.parentWidget()
        while dock is not None and not isinstance(dock, QDockWidget):
            dock = dock.parentWidget()
        window = dock.parentWidget() if dock is not None else None
        need = root.minimumSizeHint().width()
        if isinstance(window, QMainWindow) and root.width() < need:
            window.resizeDocks([dock], [need + dock.width() - root.width()],
                               Qt.Orientation.Horizontal)
    except RuntimeError:  # closed meanwhile
        pass


def combo_of(items):
    """A ``QComboBox`` that shows translated texts and keeps internal values:
    ``items`` are ``(text, value)`` pairs; read ``currentData()``, never the text."""
    from qtpy.QtWidgets import QComboBox

    combo = QComboBox()
    for text, value in items:
        combo.addItem(text, value)
    return combo


def plot_fonts() -> dict:
    """matplotlib settings for plots in the widget's language: a CJK font after the
    default one (matplotlib, unlike Qt, does not look for one itself); ``{}`` when
    the language needs none or no Noto CJK font is installed."""
    suffix = _CJK_FAMILIES.get(current_language())
    if suffix is None:
        return {}
    from matplotlib import font_manager

    names = {f.name for f in font_manager.fontManager.ttflist}
    found = [n for n in (f"Noto Sans CJK {suffix}", f"Noto Serif CJK {suffix}") if n in names]
    return {"font.family": ["DejaVu Sans", found[0]]} if found else {}


class LanguageSelector(Container):
    """A label and a combo box of the languages (their own names); the choice
    applies at once to the open docks (:func:`switch_language`) and is remembered."""

    def __init__(self):
        super().__init__(layout="horizontal", labels=False)
        self.margins = (0, 0, 0, 0)
        choices = [(tr("System language"), SYSTEM)]
        choices += [(name, code) for code, name in available_languages().items()]
        stored = resolve_language(read_language())
        tip = tr("Language of the napari-aldic docks and their messages. A new choice "
                 "applies at once (every value and the analysis stay) and is remembered.")
        self.combo = ComboBox(value=stored if stored in available_languages() else SYSTEM,
                              choices=choices, tooltip=tip)
        self.extend([Label(value=tr("Language")), self.combo])
        self.combo.changed.connect(self._on_changed)

    def _on_changed(self, code: str) -> None:
        from napari.utils.notifications import show_info

        write_language(None if code == SYSTEM else code)
        override = os.environ.get(ENV_VAR, "")
        switch_language(ui_language())  # every open dock follows (the override wins)
        if resolve_language(override) is None:
            show_info(tr("napari-aldic: language changed; the choice is remembered."))
        else:  # docs/languages.md
            show_info(tr("napari-aldic: the choice is remembered, but {var}={value} sets the "
                         "language while it is set.").format(var=ENV_VAR, value=override))
