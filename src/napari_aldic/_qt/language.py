"""The widget's language: chosen once when the widget is made, and its selector.

The order (docs/languages.md): ``NAPARI_ALDIC_LANGUAGE``; the language chosen in
the selector (remembered in the configuration folder, :mod:`.prefs`); the
environment as gettext reads it (LANGUAGE, LC_ALL, LC_MESSAGES, LANG); Qt's
``QLocale()`` (the system's language on Windows and macOS); English.
A new choice in the selector takes effect when the widget is opened again.
"""

from __future__ import annotations

import os

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
from .prefs import read_language, write_language

__all__ = ["ui_language", "apply_ui_language", "LanguageSelector", "SYSTEM", "combo_of",
           "plot_fonts"]

#: the selector's value for "follow the system"
SYSTEM = "system"
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
    """Make :func:`ui_language` the language of the process; return it."""
    return set_language(ui_language())


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
    """A label and a combo box of the languages (their own names); the choice is
    remembered and applies when the widget is opened again."""

    def __init__(self):
        super().__init__(layout="horizontal", labels=False)
        self.margins = (0, 0, 0, 0)
        choices = [(tr("System language"), SYSTEM)]
        choices += [(name, code) for code, name in available_languages().items()]
        stored = resolve_language(read_language())
        tip = tr("Language of this widget, its messages and its log. A new choice is "
                 "remembered and takes effect when the widget is opened again (close it and "
                 "open it from the Plugins menu).")
        self.combo = ComboBox(value=stored if stored in available_languages() else SYSTEM,
                              choices=choices, tooltip=tip)
        self.extend([Label(value=tr("Language")), self.combo])
        self.combo.changed.connect(self._on_changed)

    def _on_changed(self, code: str) -> None:
        from napari.utils.notifications import show_info

        write_language(None if code == SYSTEM else code)
        done = tr("napari-aldic: language saved; it applies when the widget is opened again "
                  "(close it and open it from the Plugins menu).")
        self.combo.tooltip = done
        show_info(done)
