"""Translated explanations beside the engine's English messages (no Qt here).

Engine exceptions and reason texts stay in English (they are searched for and
quoted in issues); the widget shows them unchanged and adds a translated
explanation where it knows one: the reason codes of unreliable nodes (the
engine's one table, :meth:`~napari_aldic.engine.Reason.describe`), and the typed
errors of a run (:class:`~napari_aldic.engine.DICError` by its ``code``, a run
folder that cannot be used, a lack of memory), never by the English words.
"""

from __future__ import annotations

import numpy as np

from ..engine import DICError, Reason, RunFolderError
from ..i18n import tr, tr_noop

__all__ = ["message", "reason_text", "error_code", "explain_error", "with_explanation",
           "result_summary", "REASON_TEXTS", "ERROR_HINTS"]

#: reason code -> the engine's English text (translated where shown)
REASON_TEXTS = {int(r): Reason.describe(r) for r in Reason}

#: error code -> translated explanation (see :func:`error_code`)
ERROR_HINTS = {
    "subset_too_large": tr_noop("The subset is larger than the image: choose a smaller "
                                "subset."),
    "seed_outside_roi": tr_noop("A seed point lies outside the region of interest: move it "
                                "onto the analysed material."),
    "no_seed_match": tr_noop("No seed point was found in the deformed image: move the seeds "
                             "or widen the search."),
    "shape_mismatch": tr_noop("The region of interest and the images have different "
                              "sizes."),
    "not_odd": tr_noop("This value must be an odd number."),
    "invalid_parameter": tr_noop("A correlation parameter is not valid: check the Mesh and "
                                 "correlation section."),
    "run_folder": tr_noop("The run folder cannot be used: choose another output folder."),
    "memory": tr_noop("Not enough memory: analyse a smaller region or fewer frames."),
}


def message(exc: BaseException) -> str:
    """One line describing an error."""
    msg = str(exc) or exc.__class__.__name__
    if isinstance(exc, FileNotFoundError) and not str(exc).strip():
        msg = tr("no such file: {filename}").format(filename=exc.filename)
    return " ".join(line.strip() for line in msg.splitlines() if line.strip())


def reason_text(code: int) -> str:
    """The translated meaning of a reason code (the engine's English text for an
    unknown code)."""
    text = Reason.describe(code)
    return tr(text) if int(code) in REASON_TEXTS else text


def error_code(exc: BaseException | None) -> str | None:
    """The code of an error or of the error it was raised from (a frame of
    ``track`` that could not be analysed wraps the cause), or ``None``."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, DICError):
            return exc.code
        if isinstance(exc, RunFolderError):
            return "run_folder"
        if isinstance(exc, MemoryError):
            return "memory"
        exc = exc.__cause__ or exc.__context__
    return None


def explain_error(exc: BaseException | None) -> str | None:
    """A translated explanation of an engine error, or ``None``."""
    hint = ERROR_HINTS.get(error_code(exc))
    return tr(hint) if hint is not None else None


def with_explanation(exc: BaseException) -> str:
    """The error's message (English, unchanged) followed by its translated
    explanation when one is known and the language is not English."""
    from ..i18n import current_language

    message = str(exc) or exc.__class__.__name__
    hint = explain_error(exc)
    if hint is None or current_language() == "en":
        return message
    return f"{message} ({hint})"


def result_summary(result, units=None) -> str:
    """The log's summary of a frame's DICResult, translated (the engine's own
    ``DICResult.summary()`` stays English); the AL-DIC line is the engine's.
    With ``units`` (a :class:`~napari_aldic.engine.Units` with a pixel size), u
    and v are said in its length unit, the subset and step in pixels."""
    p, valid = result.params, np.asarray(result.valid, bool)
    lines = [tr("{n} nodes ({valid} valid), subset {subset} px, step {step} px, method "
                "{method}").format(n=len(result), valid=result.n_valid, subset=p.subset,
                                   step=p.step, method=p.method)]
    if valid.any():
        scale, unit = ((1.0, "px") if units is None or units.unit == "px" else
                       (float(units.pixel_size), units.unit))
        u, v = scale * np.asarray(result.u)[valid], scale * np.asarray(result.v)[valid]
        values = dict(u_mean=u.mean(), u_min=u.min(), u_max=u.max(), v_mean=v.mean(),
                      v_min=v.min(), v_max=v.max(),
                      zncc=float(np.median(np.asarray(result.zncc)[valid])))
        lines.append(tr("u: mean {u_mean:+.4f} px [{u_min:+.3f}, {u_max:+.3f}]; v: mean "
                        "{v_mean:+.4f} px [{v_min:+.3f}, {v_max:+.3f}]; median ZNCC "
                        "{zncc:.4f}").format(**values) if unit == "px" else
                     tr("u: mean {u_mean:+.4g} {unit} [{u_min:+.4g}, {u_max:+.4g}]; v: mean "
                        "{v_mean:+.4g} {unit} [{v_min:+.4g}, {v_max:+.4g}]; median ZNCC "
                        "{zncc:.4f}").format(unit=unit, **values))
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
