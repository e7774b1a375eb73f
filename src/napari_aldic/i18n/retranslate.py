"""Saying a text shown in one language in another (no Qt here).

A widget keeps the texts it was given, not their message ids. To change the
language of an open window (docs/languages.md), a :class:`Retranslator` finds
the message behind a text of the old language (the catalogues list every
message in every language) and says it in the new one:

* a whole message: ``"Teilmenge (px)"`` -> ``"Subset (px)"`` -> ``"サブセット (px)"``;
* a message with its values filled in: the old translation, read as a pattern
  (``"Bild {frame} von {n}"``), gives the values back, and they fill the new
  translation (a value that is itself a message is said in the new language too);
* a text made of several: lines (``\\n``), HTML (``<b>...</b>``) and ``"; "``-lists
  are said piece by piece.

A text that is no message (a layer name, a number, a file name) is left as it is.
"""

from __future__ import annotations

import re
import string
from functools import lru_cache

from . import ntr as plural_of, tr
from .catalogues import catalogue_entries
from .languages import LANGUAGES, PSEUDO, SOURCE_LANGUAGE
from .pseudo import pseudo_translate

__all__ = ["Retranslator", "messages", "retranslator", "say_english"]

_FORMATTER = string.Formatter()
_TAG = re.compile(r"(<[^<>]*>)")
#: one message: ("s", msgid) or ("p", singular, plural)
Message = tuple


@lru_cache(maxsize=1)
def messages() -> tuple[tuple[str, str | None], ...]:
    """Every message id ``(singular, plural or None)`` of the catalogues."""
    seen: dict[tuple[str, str | None], None] = {}
    for lang in LANGUAGES:
        if lang != SOURCE_LANGUAGE:
            for singular, plural, _forms in catalogue_entries(lang):
                seen.setdefault((singular, plural), None)
    return tuple(seen)


@lru_cache(maxsize=16)
def _forms_in(lang: str) -> tuple[tuple[Message, tuple[str, ...]], ...]:
    """``(message, its texts in lang)`` for every message (plural: every form)."""
    out = []
    if lang in (SOURCE_LANGUAGE, PSEUDO):
        say = pseudo_translate if lang == PSEUDO else (lambda s: s)
        for singular, plural in messages():
            msg = ("s", singular) if plural is None else ("p", singular, plural)
            out.append((msg, tuple(say(t) for t in (singular, plural) if t is not None)))
        return tuple(out)
    for singular, plural, forms in catalogue_entries(lang):
        msg = ("s", singular) if plural is None else ("p", singular, plural)
        out.append((msg, tuple(f for f in forms if f)))
    return tuple(out)


def _fields(template: str) -> list[tuple[str, str | None]]:
    """``(literal text, field name or None)`` of a ``str.format`` template."""
    return [(lit, name) for lit, name, _spec, _conv in _FORMATTER.parse(template)]


def _pattern(template: str) -> re.Pattern | None:
    """A regular expression that reads the values back from a filled ``template``."""
    parts, named = [], set()
    try:
        fields = _fields(template)
    except ValueError:  # not a format template (a brace of its own)
        return None
    for literal, name in fields:
        parts.append(re.escape(literal))
        if name is None:
            continue
        if not name.isidentifier():
            return None  # positional or indexed fields: none are used
        parts.append(f"(?P={name})" if name in named else f"(?P<{name}>.*?)")
        named.add(name)
    return re.compile("".join(parts) + r"\Z", re.S) if named else None


def _plain(template: str) -> str:
    """``template`` with its fields' formats dropped (``{v:.2f}`` -> ``{v}``): the
    values read back are texts already formatted."""
    out = []
    for literal, name in _fields(template):
        out.append(literal.replace("{", "{{").replace("}", "}}"))
        if name is not None:
            out.append("{" + name + "}")
    return "".join(out)


class Retranslator:
    """Texts shown in ``old`` said in ``new`` (``new`` must be the language in use
    while :meth:`text` runs: the new texts come from :func:`tr`)."""

    def __init__(self, old: str, new: str):
        self.old, self.new = old, new
        self._exact: dict[str, Message] = {}
        self._patterns: list[tuple[str, str, str, Message]] = []  # prefix, suffix, text
        for msg, texts in _forms_in(old):
            for text in texts:
                self._exact.setdefault(text, msg)
                if "{" in text:
                    fields = _fields_or_none(text)
                    if fields and any(name for _, name in fields):
                        prefix = fields[0][0] if fields[0][1] is not None else text
                        suffix = "" if fields[-1][1] is not None else fields[-1][0]
                        self._patterns.append((prefix, suffix, text, msg))
        self._compiled: dict[str, re.Pattern | None] = {}
        self._memo: dict[str, str | None] = {}

    # ------------------------------------------------------------ one message
    def _say(self, msg: Message, values: dict | None = None) -> str | None:
        kind, *ids = msg  # the message ids of the catalogue (tr's messages)
        singular = ids[0]
        text = tr(singular) if kind == "s" else plural_of(singular, ids[1],
                                                                      _count(values or {}))
        if values is None:
            return text
        said = {k: self._value(v) for k, v in values.items()}
        try:
            return _plain(text).format_map(said)
        except (KeyError, ValueError, IndexError):
            return None

    def _value(self, value: str) -> str:
        """A value read back from a text: a message (or texts of messages) said anew."""
        return self.text(value) or value

    def _whole(self, text: str) -> str | None:
        msg = self._exact.get(text)
        if msg is not None and "{" not in text:
            return self._say(msg)
        for prefix, suffix, template, msg in self._patterns:
            if not text.startswith(prefix) or not text.endswith(suffix):
                continue
            if template not in self._compiled:
                self._compiled[template] = _pattern(template)
            pattern = self._compiled[template]
            match = pattern.match(text) if pattern is not None else None
            if match is not None and text not in match.groupdict().values():
                return self._say(msg, match.groupdict())
        return None

    # ------------------------------------------------------------ any text
    def text(self, text: str) -> str | None:
        """``text`` said in the new language, or ``None`` when it holds no message
        of the old one (or the languages are the same)."""
        if not text or not text.strip() or self.old == self.new:
            return None
        if text not in self._memo:
            if len(self._memo) > 10_000:  # texts with values (coordinates) never repeat
                self._memo.clear()
            said = self._text(text)
            self._memo[text] = None if said == text else said
        return self._memo[text]

    def _text(self, text: str) -> str | None:
        core = text.strip()
        lead, tail = text[:len(text) - len(text.lstrip())], text[len(text.rstrip()):]
        said = self._whole(core)
        if said is not None:
            return lead + said + tail
        for pieces in _splits(core):
            out = [piece if keep else (self.text(piece) or piece) for piece, keep in pieces]
            if any(new != piece for new, (piece, keep) in zip(out, pieces) if not keep):
                return lead + "".join(out) + tail
        return None


def _count(values: dict) -> int:
    """The count of a plural message: ``{n}``, else its first whole-number value."""
    for value in ([values["n"]] if "n" in values else []) + list(values.values()):
        try:
            return int(str(value).replace(",", "").strip())
        except ValueError:
            continue
    return 1


def _fields_or_none(text: str):
    try:
        return _fields(text)
    except ValueError:
        return None


def _splits(text: str):
    """Ways to cut ``text`` into ``(piece, kept as it is)`` parts, coarsest first."""
    if "\n" in text:
        yield _separated(text, "\n")
    if "<" in text and ">" in text:
        yield _tagged(text)
    for sep in ("; ", ": ", ", "):  # lists, "name: value" lines
        if sep in text:
            yield _separated(text, sep)


def _tagged(text: str) -> list[tuple[str, bool]]:
    """HTML cut into tags (kept) and texts; a text is glued to the tag after it
    when a message ends so (``"Unreliable nodes (last frame):<br>"``)."""
    pieces = [p for p in _TAG.split(text) if p]
    out, i = [], 0
    while i < len(pieces):
        piece = pieces[i]
        tag = _TAG.fullmatch(piece) is not None
        if not tag and 2 < len(pieces) and i + 1 < len(pieces) and \
                _TAG.fullmatch(pieces[i + 1]):
            out.append((piece + pieces[i + 1], False))  # said whole, or piece by piece
            i += 2
            continue
        out.append((piece, tag or not piece.strip()))
        i += 1
    return out


def _separated(text: str, sep: str) -> list[tuple[str, bool]]:
    out = []
    for i, piece in enumerate(text.split(sep)):
        if i:
            out.append((sep, True))
        out.append((piece, not piece.strip()))
    return out


@lru_cache(maxsize=16)
def retranslator(old: str, new: str) -> Retranslator:
    """The :class:`Retranslator` from ``old`` to ``new`` (made once)."""
    return Retranslator(old, new)


def say_english(text: str) -> str:
    """An English text made of messages (e.g. the engine's, which never imports the
    catalogues) in the language in use; as it is when it holds none."""
    from . import current_language

    return retranslator(SOURCE_LANGUAGE, current_language()).text(text) or text
