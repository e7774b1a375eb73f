"""Engine messages stay English; the widget adds a translated explanation (issue 17)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_aldic import i18n
from napari_aldic._qt.explain import (
    ERROR_HINTS,
    REASON_TEXTS,
    error_code,
    explain_error,
    reason_text,
    result_summary,
    with_explanation,
)
from napari_aldic.engine import (
    DICError,
    DICParams,
    Reason,
    RunFolderError,
    TrackError,
    correlate,
)
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


def _raised(fn, *args, **kwargs) -> BaseException:
    with pytest.raises(Exception) as info:
        fn(*args, **kwargs)
    return info.value


def test_reasons_and_explanations_are_translated(pseudo):
    assert reason_text(int(Reason.OUTLIER)) == pseudo_translate("outlier (median test)")
    assert reason_text(999) == Reason.describe(999)  # unknown code: the engine's text
    img = np.random.default_rng(0).random((32, 32))
    exc = _raised(correlate, img, img, subset=41)
    assert isinstance(exc, DICError) and exc.code == "subset_too_large"
    assert exc.fields == {"subset": 41, "shape": (32, 32)}
    shown = with_explanation(exc)
    assert shown.startswith(str(exc))  # the English message itself is kept for searching
    assert pseudo_translate(ERROR_HINTS["subset_too_large"]) in shown


def test_errors_are_explained_by_their_code_not_their_words():
    """A typed error keeps its explanation whatever its text says (the phrase
    matching of 0.1 missed reworded messages and caught unrelated ones)."""
    assert explain_error(DICError("not_odd", "anything", name="subset")) == \
        ERROR_HINTS["not_odd"]
    # an English phrase of an old hint in an untyped error is not matched any more
    assert explain_error(ValueError("subset=41 px is larger than the image")) is None
    # the cause of a track frame error (TrackError wraps it) is found
    try:
        try:
            DICParams(subset=30)
        except DICError as cause:
            raise TrackError("frame 3 could not be analysed", None, 3) from cause
    except TrackError as exc:
        assert error_code(exc) == "not_odd"
    assert error_code(MemoryError()) == "memory"
    assert error_code(RunFolderError("busy", ".")) == "run_folder"
    assert set(ERROR_HINTS) >= {"subset_too_large", "seed_outside_roi", "no_seed_match",
                                "shape_mismatch", "not_odd", "invalid_parameter"}


def test_no_explanation_in_english_or_for_unknown_errors():
    exc = DICError("subset_too_large", "subset=41 px is larger than the image (32 x 32 px)")
    assert explain_error(exc) == ERROR_HINTS["subset_too_large"]
    assert with_explanation(exc) == str(exc)
    assert explain_error(ValueError("something new went wrong")) is None
    assert with_explanation(ValueError("something new")) == "something new"


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
