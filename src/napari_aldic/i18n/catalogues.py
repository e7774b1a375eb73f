"""Finding and loading the gettext catalogues (``locale/<lang>/LC_MESSAGES``).

The ``.po`` files are the sources. A wheel carries the compiled ``.mo`` beside
them (built by ``hatch_build.py``); in a source checkout or an editable install
a ``.mo`` that is missing or older than its ``.po`` is compiled with Babel at
first use into the user's cache folder, named by a hash of the ``.po`` (so that
two checkouts never share a stale file; written atomically; in memory when no
folder can be written).
"""

from __future__ import annotations

import gettext
import hashlib
import io
import os
import struct
import tempfile
from pathlib import Path

__all__ = ["DOMAIN", "LOCALE_DIR", "po_path", "mo_path", "load_translations",
           "compile_catalogue", "cache_dir", "catalogue_entries"]

DOMAIN = "napari_aldic"
#: the catalogue sources, ``LOCALE_DIR/<lang>/LC_MESSAGES/napari_aldic.po``
LOCALE_DIR = Path(__file__).resolve().parent / "locale"


def po_path(lang: str) -> Path:
    """The ``.po`` source of ``lang``."""
    return LOCALE_DIR / lang / "LC_MESSAGES" / f"{DOMAIN}.po"


def mo_path(lang: str) -> Path:
    """The ``.mo`` built into a wheel for ``lang`` (beside the ``.po``)."""
    return po_path(lang).with_suffix(".mo")


def cache_dir() -> Path:
    """Where catalogues compiled at first use go (``NAPARI_ALDIC_CACHE_DIR``, else
    ``$XDG_CACHE_HOME`` or ``~/.cache``, then ``napari-aldic/locale``)."""
    env = os.environ.get("NAPARI_ALDIC_CACHE_DIR")
    if env:
        return Path(env).expanduser() / "locale"
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "napari-aldic" / "locale"


def _fresh(mo: Path, po: Path) -> bool:
    try:
        return mo.stat().st_mtime >= po.stat().st_mtime
    except OSError:
        return False


def compile_catalogue(po: Path) -> bytes:
    """The ``.mo`` bytes of the catalogue ``po`` (fuzzy entries left out, as
    ``pybabel compile`` does)."""
    from babel.messages.mofile import write_mo
    from babel.messages.pofile import read_po

    with open(po, "rb") as fh:
        catalog = read_po(fh)
    buf = io.BytesIO()
    write_mo(buf, catalog, use_fuzzy=False)
    return buf.getvalue()


def _write_atomic(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _mo_bytes(lang: str) -> bytes | None:
    po = po_path(lang)
    built = mo_path(lang)
    if built.is_file() and (not po.is_file() or _fresh(built, po)):
        return built.read_bytes()
    if not po.is_file():
        return None
    digest = hashlib.sha256(po.read_bytes()).hexdigest()[:16]
    cached = cache_dir() / lang / "LC_MESSAGES" / f"{DOMAIN}-{digest}.mo"
    if cached.is_file():
        return cached.read_bytes()
    data = compile_catalogue(po)
    try:
        _write_atomic(cached, data)
        for old in cached.parent.glob(f"{DOMAIN}-*.mo"):  # earlier versions of the .po
            if old != cached:
                old.unlink(missing_ok=True)
    except OSError:
        pass  # a read-only home: the catalogue is used from memory
    return data


def load_translations(lang: str) -> gettext.NullTranslations:
    """The translations of ``lang`` (``NullTranslations`` when there is no catalogue)."""
    data = _mo_bytes(lang)
    if data is None:
        return gettext.NullTranslations()
    return gettext.GNUTranslations(io.BytesIO(data))


def catalogue_entries(lang: str) -> list[tuple[str, str | None, list[str]]]:
    """Every message of the catalogue of ``lang``: ``(msgid, msgid_plural or None,
    translations)`` (one translation per plural form); ``[]`` without a catalogue.

    Read from the compiled ``.mo`` (gettext keeps neither the plural English text
    nor the list of messages): what :mod:`.retranslate` needs to recognise a text
    shown in one language and say it in another.
    """
    data = _mo_bytes(lang)
    if not data or len(data) < 20:
        return []
    magic = struct.unpack("<I", data[:4])[0]
    order = "<" if magic == 0x950412DE else ">"
    n, originals, translations = struct.unpack(order + "3I", data[8:20])
    out = []
    for i in range(n):
        olen, ooff = struct.unpack(order + "2I", data[originals + 8 * i:originals + 8 * i + 8])
        tlen, toff = struct.unpack(order + "2I",
                                   data[translations + 8 * i:translations + 8 * i + 8])
        msgid = data[ooff:ooff + olen].decode("utf-8")
        if not msgid or "\x04" in msgid:  # the header; message contexts (none are used)
            continue
        singular, _, plural = msgid.partition("\0")
        forms = data[toff:toff + tlen].decode("utf-8").split("\0")
        out.append((singular, plural or None, forms))
    return out
