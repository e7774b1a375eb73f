"""Translated explanations beside the engine's English messages (no Qt here).

Engine exceptions and reason texts stay in English (they are searched for and
quoted in issues); the widget shows them unchanged and adds a translated
explanation where it knows one: the reason codes of unreliable nodes, and the
kinds of error a run commonly meets (matched by a phrase of the English text).
"""

from __future__ import annotations

import numpy as np

from ..engine import Reason
from ..i18n import tr, tr_noop

__all__ = ["reason_text", "explain_error", "with_explanation", "result_summary",
           "REASON_TEXTS", "ERROR_HINTS"]

#: reason code -> what it means (translated where shown); see engine.Reason
REASON_TEXTS = {
    int(Reason.OK): tr_noop("converged"),
    int(Reason.SMALL_COMPONENT): tr_noop("subset component too small (mask)"),
    int(Reason.NOT_CONVERGED): tr_noop("not converged (iteration cap)"),
    int(Reason.OUT_OF_IMAGE): tr_noop("deformed subset leaves the image"),
    int(Reason.LOW_CORRELATION): tr_noop("low correlation (ZNCC below threshold)"),
    int(Reason.NO_TEXTURE): tr_noop("no texture in subset"),
    int(Reason.DIVERGED): tr_noop("diverged"),
    int(Reason.NO_INITIAL_GUESS): tr_noop("no initial guess"),
    int(Reason.OUTLIER): tr_noop("outlier (median test)"),
    int(Reason.POOR_MATCH): tr_noop("poor match (residual above image noise)"),
    int(Reason.BEYOND_SEARCH): tr_noop("motion beyond the search range"),
    int(Reason.UNCERTAIN): tr_noop("uncertain (noise)"),
    int(Reason.GLOBAL_MISMATCH): tr_noop("global field departs from the subset match (AL-DIC)"),
    int(Reason.STATIC_FEATURE): tr_noop("static feature (part of the subset does not move)"),
    int(Reason.AMBIGUOUS_MATCH): tr_noop(
        "ambiguous match (texture repeats within the search range)"),
}

#: (phrase of the engine's English message, translated explanation); first match wins
ERROR_HINTS = (
    ("is larger than the image", tr_noop("The subset is larger than the image: choose a "
                                         "smaller subset.")),
    ("outside the ROI", tr_noop("A seed point lies outside the region of interest: move it "
                                "onto the analysed material.")),
    ("no seed could be matched", tr_noop("No seed point was found in the deformed image: "
                                         "move the seeds or widen the search.")),
    ("differs from image shape", tr_noop("The region of interest and the images have "
                                         "different sizes.")),
    ("must be an odd", tr_noop("This value must be an odd number.")),
    ("Invalid DIC parameter", tr_noop("A correlation parameter is not valid: check the "
                                      "Mesh and correlation section.")),
    ("run folder", tr_noop("The run folder cannot be used: choose another output folder.")),
    ("out of memory", tr_noop("Not enough memory: analyse a smaller region or fewer frames.")),
    ("MemoryError", tr_noop("Not enough memory: analyse a smaller region or fewer frames.")),
)


def reason_text(code: int) -> str:
    """The translated meaning of a reason code (the engine's English text for an
    unknown code)."""
    text = REASON_TEXTS.get(int(code))
    return tr(text) if text is not None else Reason.describe(code)


def explain_error(message: str) -> str | None:
    """A translated explanation of an engine error message, or ``None``."""
    for phrase, hint in ERROR_HINTS:
        if phrase in message:
            return tr(hint)
    return None


def with_explanation(message: str) -> str:
    """``message`` (English, unchanged) followed by its translated explanation when
    one is known and the language is not English."""
    from ..i18n import current_language

    hint = explain_error(message)
    if hint is None or current_language() == "en":
        return message
    return f"{message} ({hint})"


def result_summary(result) -> str:
    """The log's summary of a frame's DICResult, translated (the engine's own
    ``DICResult.summary()`` stays English); the AL-DIC line is the engine's."""
    p, valid = result.params, np.asarray(result.valid, bool)
    lines = [tr("{n} nodes ({valid} valid), subset {subset} px, step {step} px, method "
                "{method}").format(n=len(result), valid=result.n_valid, subset=p.subset,
                                   step=p.step, method=p.method)]
    if valid.any():
        u, v = np.asarray(result.u)[valid], np.asarray(result.v)[valid]
        lines.append(tr("u: mean {u_mean:+.4f} px [{u_min:+.3f}, {u_max:+.3f}]; v: mean "
                        "{v_mean:+.4f} px [{v_min:+.3f}, {v_max:+.3f}]; median ZNCC "
                        "{zncc:.4f}").format(
            u_mean=u.mean(), u_min=u.min(), u_max=u.max(), v_mean=v.mean(), v_min=v.min(),
            v_max=v.max(), zncc=float(np.median(np.asarray(result.zncc)[valid]))))
    aldic = result.aldic_summary()
    if aldic:
        lines.append(aldic)
    conv = result.meta.get("convergence")
    if conv:
        line = (tr("IC-GN: {at_cap} nodes at the cap of {max_iter}")
                if conv.get("median_iterations") is None else
                tr("IC-GN: median {median:g} iterations, {at_cap} nodes at the cap of "
                   "{max_iter}"))
        lines.append(line.format(median=conv.get("median_iterations") or 0,
                                 at_cap=conv["at_cap"], max_iter=conv["max_iter"]))
    total = result.meta.get("timing", {}).get("total")
    if total is not None:
        lines.append(tr("time {seconds:.3f} s ({rate:,.0f} POI/s)").format(
            seconds=total, rate=len(result) / max(total, 1e-9)))
    codes, counts = np.unique(np.asarray(result.reason), return_counts=True)
    flagged = [f"{reason_text(c)}: {k}" for c, k in zip(codes, counts) if int(c) != 0]
    if flagged:
        lines.append(tr("flagged: {reasons}").format(reasons=", ".join(flagged)))
    return "\n".join(lines)
