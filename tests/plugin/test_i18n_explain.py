"""Engine messages stay English; the widget adds a translated explanation (issue 17)."""

from __future__ import annotations

import pytest

from napari_aldic import i18n
from napari_aldic._qt.explain import (
    ERROR_HINTS,
    REASON_TEXTS,
    explain_error,
    reason_text,
    result_summary,
    with_explanation,
)
from napari_aldic.engine import Reason
from napari_aldic.i18n.pseudo import pseudo_translate


@pytest.fixture
def pseudo():
    i18n.set_language("qps")
    yield
    i18n.set_language("en")


def test_every_reason_code_has_its_engine_text():
    """The translated legend starts from the engine's own English descriptions."""
    codes = [int(r) for r in Reason]
    assert sorted(REASON_TEXTS) == sorted(codes)
    for code in codes:
        assert REASON_TEXTS[code] == Reason.describe(code)
        assert reason_text(code) == Reason.describe(code)  # English: unchanged


def test_reasons_and_explanations_are_translated(pseudo):
    assert reason_text(int(Reason.OUTLIER)) == pseudo_translate("outlier (median test)")
    assert reason_text(999) == Reason.describe(999)  # unknown code: the engine's text
    engine = "subset=41 px is larger than the image (32 x 32 px)"
    shown = with_explanation(engine)
    assert shown.startswith(engine)  # the English message itself is kept for searching
    assert pseudo_translate(ERROR_HINTS[0][1]) in shown


def test_no_explanation_in_english_or_for_unknown_errors():
    engine = "subset=41 px is larger than the image (32 x 32 px)"
    assert explain_error(engine) == ERROR_HINTS[0][1]
    assert with_explanation(engine) == engine
    assert explain_error("something new went wrong") is None
    assert with_explanation("something new went wrong") == "something new went wrong"


def test_result_summary_translated_and_complete(pseudo, export_sequence):
    """The log's summary of a frame: the same facts as the engine's English summary."""
    res = export_sequence[2]
    text = result_summary(res)
    assert text.count("\n") == res.summary().count("\n")
    first = text.splitlines()[0]
    assert first == pseudo_translate(
        "{n} nodes ({valid} valid), subset {subset} px, step {step} px, method "
        "{method}").format(n=len(res), valid=res.n_valid, subset=res.params.subset,
                           step=res.params.step, method=res.params.method)
    assert f"{res.u[res.valid].mean():+.4f}" in text
