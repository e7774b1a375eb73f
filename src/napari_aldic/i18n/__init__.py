"""Translation of the plugin's and the CLI's user-visible text (gettext catalogues).

Every user-visible string of the napari side and the command line goes through
:func:`tr` (message ids are the English text; placeholders are filled after
translation: ``tr("Found {n} nodes").format(n=n)``), plural forms through
:func:`ntr`. Texts defined at import time are marked with :func:`tr_noop` and
translated where they are shown. The engine never imports this package: its
exceptions stay in English.

The language is chosen once per process (:func:`set_language`); by default it
comes from the environment (``NAPARI_ALDIC_LANGUAGE``, then LANGUAGE, LC_ALL,
LC_MESSAGES, LANG). See docs/languages.md.
"""

from __future__ import annotations

import gettext

from .catalogues import load_translations
from .languages import (
    ENV_VAR,
    LANGUAGES,
    PSEUDO,
    SOURCE_LANGUAGE,
    language_from_environment,
    resolve_language,
)
from .pseudo import pseudo_translate

__all__ = ["tr", "ntr", "tr_noop", "current_language", "set_language", "available_languages",
           "resolve_language", "language_from_environment", "LANGUAGES", "PSEUDO", "ENV_VAR"]

_state: dict = {"lang": None, "translations": None}


def set_language(code: str | None) -> str:
    """Speak ``code`` (a supported code or any locale name; ``None``: the
    environment's language) from now on; returns the language in use."""
    lang = language_from_environment() if code is None else resolve_language(code)
    lang = lang or SOURCE_LANGUAGE
    if lang in (SOURCE_LANGUAGE, PSEUDO):
        translations = gettext.NullTranslations()
    else:
        translations = load_translations(lang)
    _state.update(lang=lang, translations=translations)
    return lang


def current_language() -> str:
    """The language code in use (the environment's until :func:`set_language`)."""
    if _state["lang"] is None:
        set_language(None)
    return _state["lang"]


def available_languages() -> dict[str, str]:
    """The selectable languages: code -> the language's own name."""
    return dict(LANGUAGES)


def tr(message: str) -> str:
    """The translation of ``message`` (English text) in the current language."""
    lang = current_language()
    if lang == PSEUDO:
        return pseudo_translate(message)
    return _state["translations"].gettext(message)


def ntr(singular: str, plural: str, n: int) -> str:
    """The translation of ``singular``/``plural`` for the count ``n`` (the
    language's plural rule); fill ``{n}`` afterwards with ``.format(n=n)``."""
    lang = current_language()
    if lang == PSEUDO:
        return pseudo_translate(singular if n == 1 else plural)
    return _state["translations"].ngettext(singular, plural, n)


def tr_noop(message: str) -> str:
    """Mark ``message`` for extraction without translating it (texts defined at
    import time; pass them to :func:`tr` where they are shown)."""
    return message
