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
import tempfile
from pathlib import Path

__all__ = ["DOMAIN", "LOCALE_DIR", "po_path", "mo_path", "load_translations",
           "compile_catalogue", "cache_dir"]

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
