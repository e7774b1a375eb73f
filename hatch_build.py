"""Hatch build hook: compile the gettext catalogues (.po -> .mo) into the wheel.

The ``.po`` sources live in ``src/napari_aldic/i18n/locale/<lang>/LC_MESSAGES``; the
compiled ``.mo`` files are build outputs (not in the repository). An editable
install compiles them at first use instead (napari_aldic.i18n.catalogues).
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

from hatchling.builders.hooks.plugin.interface import BuildHookInterface

LOCALE = Path("src") / "napari_aldic" / "i18n" / "locale"
DOMAIN = "napari_aldic"


class CatalogueBuildHook(BuildHookInterface):
    """Adds ``napari_aldic/i18n/locale/<lang>/LC_MESSAGES/napari_aldic.mo`` to wheels."""

    PLUGIN_NAME = "custom"

    def initialize(self, version: str, build_data: dict) -> None:
        if self.target_name != "wheel" or version == "editable":
            return
        from babel.messages.mofile import write_mo
        from babel.messages.pofile import read_po

        self._tmp = Path(tempfile.mkdtemp(prefix="napari_aldic_mo_"))
        root = Path(self.root)
        for po in sorted((root / LOCALE).glob(f"*/LC_MESSAGES/{DOMAIN}.po")):
            with open(po, "rb") as fh:
                catalog = read_po(fh)
            rel = po.relative_to(root / LOCALE).with_suffix(".mo")
            mo = self._tmp / rel
            mo.parent.mkdir(parents=True, exist_ok=True)
            with open(mo, "wb") as fh:
                write_mo(fh, catalog, use_fuzzy=False)
            target = f"napari_aldic/i18n/locale/{rel.as_posix()}"
            build_data["force_include"][str(mo)] = target

    def finalize(self, version: str, build_data: dict, artifact_path: str) -> None:
        tmp = getattr(self, "_tmp", None)
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
