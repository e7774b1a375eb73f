"""Which language to speak: the supported languages and the locale fallback rules.

No Qt and no napari here (the CLI uses it too). A locale name such as
``de_AT.UTF-8``, ``zh-Hant-HK`` or ``fr_CA@euro`` is reduced to one of
:data:`LANGUAGES` (regional variants to their base language, Chinese by script
or region), unknown languages to English.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping

__all__ = ["LANGUAGES", "PSEUDO", "ENV_VAR", "SOURCE_LANGUAGE", "resolve_language",
           "environment_languages", "language_from_environment"]

#: the supported languages: code -> the language's own name (shown in the selector)
LANGUAGES = {"en": "English", "zh_CN": "简体中文", "zh_TW": "繁體中文", "ja": "日本語",
             "ko": "한국어", "de": "Deutsch", "fr": "Français", "es": "Español"}
#: the language of the message ids (no catalogue)
SOURCE_LANGUAGE = "en"
#: the pseudo-locale: every translated text visibly transformed (finds untranslated text)
PSEUDO = "qps"
#: the environment variable that overrides every other choice (also used by the tests)
ENV_VAR = "NAPARI_ALDIC_LANGUAGE"
#: the variables gettext reads, in its order (the first one set counts)
GETTEXT_VARS = ("LANGUAGE", "LC_ALL", "LC_MESSAGES", "LANG")

_TRADITIONAL = {"tw", "hk", "mo", "hant"}


def _parts(name: str) -> list[str]:
    """``'zh-Hant_HK.UTF-8@x'`` -> ``['zh', 'hant', 'hk']`` (lower case)."""
    name = name.split(".", 1)[0].split("@", 1)[0].replace("-", "_")
    return [p.lower() for p in name.split("_") if p]


def resolve_language(name: str | None) -> str | None:
    """The supported language code for the locale ``name``; ``"en"`` for ``C``,
    ``POSIX`` and English; ``None`` when the language is not supported.

    >>> resolve_language("de_AT.UTF-8"), resolve_language("zh_HK"), resolve_language("pt_BR")
    ('de', 'zh_TW', None)
    """
    if not name:
        return None
    if name.strip() in ("C", "POSIX") or name.strip().startswith("C."):
        return SOURCE_LANGUAGE
    parts = _parts(name.strip())
    if not parts:
        return None
    base = parts[0]
    if base == PSEUDO:
        return PSEUDO
    if base == "zh":
        return "zh_TW" if _TRADITIONAL & set(parts[1:]) else "zh_CN"
    return base if base in LANGUAGES else None


def environment_languages(env: Mapping[str, str] | None = None) -> list[str] | None:
    """The locale names of the first of LANGUAGE (a colon list), LC_ALL,
    LC_MESSAGES, LANG that is set (as gettext reads them); ``None`` when none is."""
    env = os.environ if env is None else env
    for var in GETTEXT_VARS:
        value = env.get(var, "")
        if value:
            return [v for v in value.split(":") if v]
    return None


def _first_supported(names: Iterable[str]) -> str | None:
    for name in names:
        code = resolve_language(name)
        if code is not None:
            return code
    return None


def language_from_environment(env: Mapping[str, str] | None = None,
                              fallback: str | None = None) -> str:
    """The language of the environment: :data:`ENV_VAR` first, then the gettext
    variables; ``fallback`` (e.g. Qt's ``QLocale().name()``) when none of them is
    set; English when nothing is supported."""
    env = os.environ if env is None else env
    override = resolve_language(env.get(ENV_VAR, ""))
    if override is not None:
        return override
    names = environment_languages(env)
    if names is None:
        names = [fallback] if fallback else []
    return _first_supported(names) or SOURCE_LANGUAGE
