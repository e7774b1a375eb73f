"""The translation catalogues (issue 17) and the language rules, without napari or Qt.

* every message of the template is translated in each of the seven languages: no
  missing, empty or fuzzy entry, no English left except the names/units/symbols of
  :data:`SAME_AS_ENGLISH`, the same ``{placeholders}`` (and ``%`` formats) as the
  English text;
* the template is up to date with the source (extracted again into a temporary file);
* every ``tr()`` call takes a literal (or a constant marked with ``tr_noop``), never an
  f-string or a concatenation;
* the locale fallback rules, the pseudo-locale, and the compilation at first use.

The completeness tests fail until the translators have filled the catalogues: that is
intended (see docs/languages.md).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from napari_aldic import i18n
from napari_aldic.i18n import catalogues, languages
from napari_aldic.i18n.pseudo import CLOSE, OPEN, pseudo_translate

REPO = Path(__file__).resolve().parents[2]
SRC = REPO / "src" / "napari_aldic"
LOCALE = SRC / "i18n" / "locale"
POT = LOCALE / "napari_aldic.pot"
TRANSLATED = ("zh_CN", "zh_TW", "ja", "ko", "de", "fr", "es")

#: message ids whose translation may equal the English text: names, units, symbols,
#: file filters. "*": every language; a language code: that language only (e.g. words
#: that are the same in German or French). Add an entry only with a reason.
SAME_AS_ENGLISH: dict[str, set[str]] = {
    "*": {"AL-DIC", "AL-DVC", "MATLAB (.mat)", "MATLAB (*.mat)", "CSV (*.csv)", "PNG (*.png)",
          "GIF (*.gif)", "PDF (*.pdf)", "ZNCC", "px", "µm", "mm", "{prog}: error: {message}"},
    "de": {"Format", "Export", "Subset (px)", "Tracking", "Status", "Name"},
    "fr": {"Format", "Local (IC-GN)", "Export", "Position", "Regions", "Zones",
           "options"},  # the CLI help heading: the same word in French
    "es": {"Local (IC-GN)"},
    "zh_CN": set(), "zh_TW": set(), "ja": set(), "ko": set(),
}

_BRACES = re.compile(r"(?<!\{)\{[^{}]*\}(?!\})")
_PERCENT = re.compile(r"%(?:\([^)]*\))?[-#0 +]*\d*(?:\.\d+)?[sdifgeEr%]")


def _read(path: Path):
    from babel.messages.pofile import read_po

    with open(path, "rb") as fh:
        return read_po(fh)


def _ids(catalog) -> set:
    return {m.id for m in catalog if m.id}


def _placeholders(text: str) -> list[str]:
    return sorted(_BRACES.findall(text.replace("{{", "").replace("}}", "")))


def _percent(text: str) -> list[str]:
    return sorted(_PERCENT.findall(text))


def _has_words(text: str) -> bool:
    """Whether ``text`` has words to translate (not only placeholders, tags, numbers)."""
    bare = re.sub(r"<[^<>]*>|&[#\w]+;", " ", _BRACES.sub(" ", text))
    return re.search(r"[^\W\d_]{2}", bare) is not None


def _strings(msgid) -> tuple:
    return msgid if isinstance(msgid, tuple) else (msgid,)


# ------------------------------------------------------------------ catalogues
@pytest.fixture(scope="module")
def template():
    return _read(POT)


def test_template_has_the_plugin_and_cli_messages(template):
    ids = _ids(template)
    assert len(ids) > 400
    # a widget label, a CLI help line, a section title (tr_noop) and an export format
    for msgid in ("Subset (px)", "analyse a synthetic speckle pair with exact truth",
                  "3. Strain", "PDF report (.pdf)", "Language"):
        assert msgid in ids, msgid


@pytest.mark.parametrize("lang", TRANSLATED)
def test_catalogue_is_complete(template, lang):
    """Every message translated: no missing, empty, fuzzy or English entry."""
    po = LOCALE / lang / "LC_MESSAGES" / "napari_aldic.po"
    assert po.is_file(), f"no catalogue {po} (pybabel init, see docs/languages.md)"
    catalog = _read(po)
    allowed = SAME_AS_ENGLISH["*"] | SAME_AS_ENGLISH.get(lang, set())
    missing, empty, fuzzy, english = [], [], [], []
    for m in template:
        if not m.id:
            continue
        t = catalog.get(m.id)
        if t is None:
            missing.append(m.id)
            continue
        strs = _strings(t.string)
        if not all(strs):
            empty.append(m.id)
        elif t.fuzzy:
            fuzzy.append(m.id)
        elif strs[0] == _strings(m.id)[0] and _strings(m.id)[0] not in allowed and \
                _has_words(_strings(m.id)[0]):
            english.append(m.id)
    problems = [(what, ids) for what, ids in (("missing", missing), ("empty", empty),
                                               ("fuzzy", fuzzy), ("left in English", english))
                if ids]
    assert not problems, f"{lang}: " + "; ".join(
        f"{len(ids)} {what} (e.g. {ids[:3]})" for what, ids in problems)


@pytest.mark.parametrize("lang", TRANSLATED)
def test_translations_keep_the_placeholders(lang):
    """The same ``{name}`` fields and ``%`` formats as the English text (a missing or
    renamed field would raise KeyError in ``.format`` or lose a value)."""
    catalog = _read(LOCALE / lang / "LC_MESSAGES" / "napari_aldic.po")
    bad = []
    for m in catalog:
        if not m.id or not any(_strings(m.string)) or m.fuzzy:
            continue  # fuzzy entries are not used (and fail test_catalogue_is_complete)
        english = _strings(m.id)
        for i, text in enumerate(_strings(m.string)):
            source = english[min(i, len(english) - 1)]
            if _placeholders(text) != _placeholders(source) or \
                    _percent(text) != _percent(source):
                bad.append(f"{source!r} -> {text!r}")
    assert not bad, f"{lang}: {len(bad)} translations change the placeholders:\n  " + \
        "\n  ".join(bad[:10])


@pytest.mark.parametrize("lang", TRANSLATED)
def test_each_language_keeps_a_glossary(lang):
    """The fixed DIC terms of the language (subset, step, strain ...), one file each."""
    glossary = LOCALE / lang / "glossary.md"
    assert glossary.is_file(), f"no glossary {glossary}"
    text = glossary.read_text(encoding="utf-8")
    assert "subset" in text.lower() and len(text.splitlines()) >= 10, glossary


def test_catalogue_headers_name_their_language():
    for lang in TRANSLATED:
        catalog = _read(LOCALE / lang / "LC_MESSAGES" / "napari_aldic.po")
        assert catalog.locale is not None and str(catalog.locale).split("_")[0] == \
            lang.split("_")[0], lang


def test_template_is_up_to_date(tmp_path, template):
    """Extracting again finds exactly the template's messages (a new ``tr()`` string
    without ``pybabel extract`` fails here)."""
    from babel.messages.frontend import CommandLineInterface

    out = tmp_path / "fresh.pot"
    CommandLineInterface().run(
        ["pybabel", "-q", "extract", "-F", str(REPO / "babel.cfg"), "--no-default-keywords",
         "-k", "tr", "-k", "tr_noop", "-k", "ntr:1,2", "-o", str(out), str(SRC),
         str(SRC / "_qt")])
    fresh, known = _ids(_read(out)), _ids(template)
    assert fresh - known == set(), ("strings not in the template (run pybabel extract and "
                                    f"update, docs/languages.md): {sorted(fresh - known)[:10]}")
    assert known - fresh == set(), f"template strings no longer in the source: " \
        f"{sorted(known - fresh)[:10]}"


def test_messages_have_named_placeholders(template):
    """Translators may reorder fields: ``{}`` or ``{0}`` would not survive that."""
    bad = [m.id for m in template if m.id for s in _strings(m.id)
           for f in _placeholders(s) if re.fullmatch(r"\{\d*(?:[:!].*)?\}", f)]
    assert not bad, bad


# ------------------------------------------------------------------ the source
def _tr_calls():
    for path in sorted(SRC.rglob("*.py")):
        if "engine" in path.relative_to(SRC).parts:
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and \
                    node.func.id in ("tr", "tr_noop", "ntr") and node.args:
                yield path, node


def test_tr_takes_whole_literal_messages():
    """``tr("... {x}").format(x=...)``: never an f-string, a concatenation or a
    ``%`` formatting inside ``tr()`` (the message id must be the literal text)."""
    bad = []
    for path, node in _tr_calls():
        for arg in node.args[:2 if node.func.id == "ntr" else 1]:
            literal = isinstance(arg, ast.Constant) and isinstance(arg.value, str)
            marked = node.func.id == "tr" and isinstance(arg, (ast.Name, ast.Attribute,
                                                               ast.Subscript, ast.IfExp))
            if not (literal or marked) or (node.func.id == "tr_noop" and not literal):
                bad.append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert not bad, bad


def test_the_engine_never_translates():
    engine = SRC / "engine"
    users = [p for p in engine.rglob("*.py") if "i18n" in p.read_text(encoding="utf-8")]
    assert not users, users


# ------------------------------------------------------------------ language rules
@pytest.mark.parametrize("name, code", [
    ("de_AT.UTF-8", "de"), ("de_CH", "de"), ("de", "de"), ("fr_CA", "fr"), ("es_MX", "es"),
    ("zh_HK", "zh_TW"), ("zh_MO", "zh_TW"), ("zh-Hant", "zh_TW"), ("zh_Hant_HK", "zh_TW"),
    ("zh_TW.Big5", "zh_TW"), ("zh_SG", "zh_CN"), ("zh_Hans", "zh_CN"), ("zh", "zh_CN"),
    ("ja_JP.UTF-8", "ja"), ("ko_KR", "ko"), ("en_GB", "en"), ("C", "en"), ("POSIX", "en"),
    ("C.UTF-8", "en"), ("qps", "qps"), ("pt_BR", None), ("xx", None), ("", None)])
def test_resolve_language(name, code):
    assert i18n.resolve_language(name) == code


@pytest.mark.parametrize("env, code", [
    ({"LANGUAGE": "xx:fr:de", "LANG": "de_DE.UTF-8"}, "fr"),  # the first supported of the list
    ({"LANGUAGE": "pt_BR:zh_HK", "LANG": "en_US"}, "zh_TW"),
    ({"LC_ALL": "de_AT.UTF-8", "LANG": "fr_FR.UTF-8"}, "de"),  # LC_ALL beats LANG
    ({"LC_MESSAGES": "ja_JP.UTF-8", "LANG": "fr_FR.UTF-8"}, "ja"),
    ({"LANG": "es_MX.UTF-8"}, "es"),
    ({"LANG": "C"}, "en"), ({"LANG": "pt_BR.UTF-8"}, "en"),  # unknown: English
    ({}, "en"),
    ({"NAPARI_ALDIC_LANGUAGE": "ko", "LANG": "de_DE"}, "ko"),  # the override first
])
def test_language_from_environment(env, code):
    assert i18n.language_from_environment(env) == code


def test_fallback_is_used_only_without_environment():
    """Qt's QLocale name (the widget's fallback) counts only when no variable is set."""
    assert i18n.language_from_environment({}, fallback="zh_TW") == "zh_TW"
    assert i18n.language_from_environment({"LANG": "fr_FR"}, fallback="zh_TW") == "fr"
    assert languages.environment_languages({"LANGUAGE": "de:fr"}) == ["de", "fr"]


def test_available_languages_are_the_eight():
    names = i18n.available_languages()
    assert names == {"en": "English", "zh_CN": "简体中文", "zh_TW": "繁體中文", "ja": "日本語",
                     "ko": "한국어", "de": "Deutsch", "fr": "Français", "es": "Español"}
    assert set(TRANSLATED) == set(names) - {"en"}
    assert i18n.PSEUDO not in names  # the pseudo-locale is not offered in the selector


# ------------------------------------------------------------------ pseudo-locale, runtime
def test_pseudo_translation_keeps_placeholders_and_markup():
    text = pseudo_translate("Subset {subset} px is {value:.2f}; <b>x</b> 100%% &amp; %(n)s")
    assert text.startswith(OPEN) and text.endswith(CLOSE)
    for kept in ("{subset}", "{value:.2f}", "<b>", "</b>", "%%", "&amp;", "%(n)s"):
        assert kept in text
    assert "Subset" not in text  # the letters are visibly changed
    assert text.format(subset=31, value=0.5).count("31") == 1


@pytest.fixture
def language():
    """Restore the language of the tests (English) afterwards."""
    yield i18n.set_language
    i18n.set_language("en")


def test_tr_in_the_pseudo_locale_and_back(language):
    assert language("qps") == "qps" and i18n.current_language() == "qps"
    assert i18n.tr("Run").startswith(OPEN)
    assert i18n.ntr("{n} frame", "{n} frames", 2).format(n=2) == pseudo_translate("{n} frames") \
        .format(n=2)
    assert language("de_AT.UTF-8") == "de"
    assert language("pt_BR") == "en" and i18n.tr("Run") == "Run"


def test_catalogue_compiled_at_first_use_and_after_a_change(tmp_path, monkeypatch, language):
    """A source checkout has only the .po: it is compiled into the cache folder, and
    again when the .po is newer than the compiled file."""
    locale = tmp_path / "locale"
    po = locale / "de" / "LC_MESSAGES" / "napari_aldic.po"
    po.parent.mkdir(parents=True)

    def write(text: str) -> None:
        po.write_text('msgid ""\nmsgstr ""\n"Content-Type: text/plain; charset=UTF-8\\n"\n'
                      '"Plural-Forms: nplurals=2; plural=(n != 1);\\n"\n\n'
                      f'msgid "Run"\nmsgstr "{text}"\n\n'
                      'msgid "{n} frame"\nmsgid_plural "{n} frames"\n'
                      'msgstr[0] "{n} Bild"\nmsgstr[1] "{n} Bilder"\n', encoding="utf-8")

    write("Starten")
    monkeypatch.setattr(catalogues, "LOCALE_DIR", locale)
    monkeypatch.setenv("NAPARI_ALDIC_CACHE_DIR", str(tmp_path / "cache"))
    language("de")
    assert i18n.tr("Run") == "Starten"
    assert i18n.ntr("{n} frame", "{n} frames", 3).format(n=3) == "3 Bilder"
    assert i18n.tr("not in the catalogue") == "not in the catalogue"
    folder = tmp_path / "cache" / "locale" / "de" / "LC_MESSAGES"
    assert len(list(folder.glob("napari_aldic-*.mo"))) == 1
    write("Los")  # the catalogue changed: compiled again (its own cache file)
    language("de")
    assert i18n.tr("Run") == "Los"
    assert len(list(folder.glob("napari_aldic-*.mo"))) == 1  # the old one is removed
    language("de")  # from the cache now
    assert i18n.tr("Run") == "Los"
    assert not list(tmp_path.rglob("*.tmp"))  # the atomic write left nothing behind
