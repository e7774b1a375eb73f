"""Reading a shown text back to its message and saying it in another language
(napari_aldic.i18n.retranslate, the live language change of issue 24)."""

from __future__ import annotations

import pytest

from napari_aldic import i18n
from napari_aldic.i18n.retranslate import Retranslator, messages


@pytest.fixture
def to():
    """``to(old, new)``: a Retranslator, with ``new`` the language in use."""
    def make(old: str, new: str) -> Retranslator:
        i18n.set_language(new)
        return Retranslator(old, new)

    yield make
    i18n.set_language("en")


def _in(lang: str, message: str) -> str:
    i18n.set_language(lang)
    return i18n.tr(message)


def test_every_message_of_the_template_is_known():
    ids = {singular for singular, _ in messages()}
    assert len(ids) > 700 and "Subset (px)" in ids and "3. Strain" in ids


def test_whole_messages_values_plurals_and_markup(to):
    de_step, de_strain = _in("de", "Step (px)"), _in("de", "3. Strain")
    rt = to("en", "de")
    assert rt.text("Step (px)") == de_step != "Step (px)"
    assert rt.text("  3. Strain ") == f"  {de_strain} "  # the spaces around stay
    assert rt.text("<b>3. Strain</b>") == f"<b>{de_strain}</b>"
    assert rt.text("Step (px)\n3. Strain") == f"{de_step}\n{de_strain}"
    # a message with its values: read back, said with them
    assert rt.text("napari-aldic: cancelled; 3 finished frames kept") == \
        "napari-aldic: abgebrochen; 3 fertige Bilder behalten"
    assert rt.text("napari-aldic: cancelled; 1 finished frame kept") == \
        "napari-aldic: abgebrochen; 1 fertiges Bild behalten"
    # a value that is a message itself is said anew
    assert rt.text("line1: degraded at frame(s) 1, 2: not computable") == \
        "line1: beeinträchtigt in Bild(ern) 1, 2: nicht berechenbar"
    # what is no message stays (layer names, numbers, file names)
    for text in ("speckle", "DIC u [px]", "42", "run1/frame_00002.npz", ""):
        assert rt.text(text) is None


def test_from_one_translation_to_another_and_the_pseudo_locale(to):
    ja = _in("ja", "Step (px)")
    de = _in("de", "Step (px)")
    assert to("de", "ja").text(de) == ja
    assert to("ja", "qps").text(ja) == "⟦Stép (px)⟧"
    assert to("qps", "en").text("⟦Stép (px)⟧") == "Step (px)"
    assert to("de", "de").text(de) is None  # the same language: nothing to do
