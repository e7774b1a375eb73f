"""The command line speaks the environment's language (issue 17): its help and
messages go through the catalogues; checked with the pseudo-locale ``qps`` (no
dependence on the translators' work) and, for German, against the catalogue."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from napari_aldic import i18n
from napari_aldic.cli import main
from napari_aldic.i18n.pseudo import OPEN, pseudo_translate

_GETTEXT_VARS = ("LANGUAGE", "LC_ALL", "LC_MESSAGES", "LANG")


@pytest.fixture
def environment(monkeypatch):
    """``environment(**vars)``: only these language variables set; English again after."""
    def set_env(**values):
        for var in (*_GETTEXT_VARS, i18n.ENV_VAR):
            monkeypatch.delenv(var, raising=False)
        for var, value in values.items():
            monkeypatch.setenv(var, value)

    yield set_env
    i18n.set_language("en")


def _help(capsys, argv) -> str:
    assert main(argv) == 0
    return " ".join(capsys.readouterr().out.split())  # argparse wraps lines


def test_help_in_the_pseudo_locale(environment, capsys):
    environment(NAPARI_ALDIC_LANGUAGE="qps")
    text = _help(capsys, ["--help"])
    assert pseudo_translate("2-D digital image correlation (napari-aldic engine).") in text
    assert pseudo_translate("analyse a synthetic speckle pair with exact truth") in text
    for heading in ("usage:", "options", "show this help message and exit"):
        assert pseudo_translate(heading) in text  # argparse's own texts too
    sub = _help(capsys, ["demo", "--help"])
    assert pseudo_translate("speckle pattern seed (default 0)") in sub
    assert "--seed" in sub and "--out" in sub  # option names are never translated


def test_help_is_english_by_default(environment, capsys):
    environment(LANG="C")
    text = _help(capsys, ["--help"])
    assert "2-D digital image correlation (napari-aldic engine)." in text
    assert OPEN not in text


def test_error_message_in_the_pseudo_locale(environment, capsys):
    environment(LANGUAGE="qps:de")
    assert main(["run", "no_such_image.tif", "other.tif"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(pseudo_translate("{prog}: error: {message}").split("{")[0])
    assert "no_such_image.tif" in err


def test_lang_de_gives_the_german_catalogue(tmp_path):
    """``LANG=de_DE.UTF-8 napari-aldic --help`` shows the German help line of the
    catalogue (the English text while it is untranslated)."""
    from babel.messages.pofile import read_po

    msgid = "analyse a synthetic speckle pair with exact truth"
    po = i18n.catalogues.po_path("de")
    with open(po, "rb") as fh:
        entry = read_po(fh).get(msgid)
    expected = entry.string if entry is not None and entry.string and not entry.fuzzy \
        else msgid
    env = {k: v for k, v in os.environ.items()
           if k not in (*_GETTEXT_VARS, i18n.ENV_VAR)}
    env.update(LANG="de_DE.UTF-8", NAPARI_ALDIC_CACHE_DIR=str(tmp_path))
    proc = subprocess.run([sys.executable, "-m", "napari_aldic.cli", "--help"], env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert " ".join(expected.split()) in " ".join(proc.stdout.split())
