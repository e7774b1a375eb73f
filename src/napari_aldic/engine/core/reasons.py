"""Reason codes explaining why a node is (or is not) trusted, their one table of
text and colour, and :class:`DICError`, the typed error of a run that cannot start.

The texts are English (they are searched for and quoted in issues); the widget
translates them (``tr_noop`` below only marks them for the message catalogue:
the engine itself never translates).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Any

__all__ = ["Reason", "ReasonInfo", "REASONS", "DICError"]


def tr_noop(text: str) -> str:
    """Mark ``text`` for the translation catalogue (returned unchanged)."""
    return text

class Reason(IntEnum):
    """Why a node is flagged; ``OK`` (0) means converged and trusted."""

    OK = 0
    #: the mask-connected part of the subset holds under ``min_component`` of its area
    SMALL_COMPONENT = 1
    #: IC-GN hit its iteration cap without meeting the tolerance
    NOT_CONVERGED = 2
    #: the deformed subset leaves the image
    OUT_OF_IMAGE = 3
    #: final ZNCC below ``zncc_min``
    LOW_CORRELATION = 4
    #: subset has too little texture (flat grey levels, singular Hessian)
    NO_TEXTURE = 5
    #: the iteration diverged (displacement update beyond the subset size)
    DIVERGED = 6
    #: no initial guess could be found (no converged neighbour, failed search)
    NO_INITIAL_GUESS = 7
    #: displacement inconsistent with its mask-connected neighbours (median test)
    OUTLIER = 8
    #: converged, but the match residual is far above what image noise allows
    #: (``zncc_rel``): most likely a spurious match
    POOR_MATCH = 9
    #: no acceptable match within the widest search range (``search_max``):
    #: the motion is probably beyond it
    BEYOND_SEARCH = 10
    #: predicted standard uncertainty of ``u`` or ``v`` above ``max_uncertainty``
    UNCERTAIN = 11
    #: AL-DIC: the subset matches the global field's warp clearly worse than
    #: its own local match, beyond what noise allows (e.g. a field smoothed
    #: across an unmasked crack)
    GLOBAL_MISMATCH = 12
    #: part of the subset is explained better by zero motion than by the
    #: match: features that do not move with the material (an occluder, a
    #: bar or dust fixed in the view, the black edge of the field of view)
    STATIC_FEATURE = 13
    #: the subset's texture repeats within the search range (a second
    #: autocorrelation peak nearly as high as the match): aliases match too
    AMBIGUOUS_MATCH = 14

    @classmethod
    def describe(cls, code: int) -> str:
        """Human-readable (English) text of a reason code."""
        info = REASONS.get(int(code))
        return info.text if info is not None else f"unknown ({code})"

    @classmethod
    def colour(cls, code: int) -> str:
        """The colour (``#rrggbb``) of a reason code in every figure and layer
        (black for an unknown code)."""
        info = REASONS.get(int(code))
        return info.colour if info is not None else "#000000"


@dataclass(frozen=True)
class ReasonInfo:
    """What a reason code means (English) and its colour (``#rrggbb``)."""

    text: str
    colour: str


#: the one table of reason codes: text and colour (tab10 and a few darker ones, no
#: two alike; green only for converged)
REASONS: dict[int, ReasonInfo] = {
    Reason.OK: ReasonInfo(tr_noop("converged"), "#2ca02c"),
    Reason.SMALL_COMPONENT: ReasonInfo(tr_noop("subset component too small (mask)"),
                                       "#1f77b4"),
    Reason.NOT_CONVERGED: ReasonInfo(tr_noop("not converged (iteration cap)"), "#ff7f0e"),
    Reason.OUT_OF_IMAGE: ReasonInfo(tr_noop("deformed subset leaves the image"), "#d62728"),
    Reason.LOW_CORRELATION: ReasonInfo(tr_noop("low correlation (ZNCC below threshold)"),
                                       "#9467bd"),
    Reason.NO_TEXTURE: ReasonInfo(tr_noop("no texture in subset"), "#8c564b"),
    Reason.DIVERGED: ReasonInfo(tr_noop("diverged"), "#e377c2"),
    Reason.NO_INITIAL_GUESS: ReasonInfo(tr_noop("no initial guess"), "#bcbd22"),
    Reason.OUTLIER: ReasonInfo(tr_noop("outlier (median test)"), "#17becf"),
    Reason.POOR_MATCH: ReasonInfo(tr_noop("poor match (residual above image noise)"),
                                  "#7f7f7f"),
    Reason.BEYOND_SEARCH: ReasonInfo(tr_noop("motion beyond the search range"), "#000080"),
    Reason.UNCERTAIN: ReasonInfo(tr_noop("uncertain (noise)"), "#ffd700"),
    Reason.GLOBAL_MISMATCH: ReasonInfo(
        tr_noop("global field departs from the subset match (AL-DIC)"), "#800000"),
    Reason.STATIC_FEATURE: ReasonInfo(
        tr_noop("static feature (part of the subset does not move)"), "#556b2f"),
    Reason.AMBIGUOUS_MATCH: ReasonInfo(
        tr_noop("ambiguous match (texture repeats within the search range)"), "#ff1493"),
}


class DICError(ValueError):
    """An analysis that cannot run as asked, with a machine-readable ``code``
    and the values involved in ``fields`` (the message stays English).

    Codes: ``"invalid_parameter"``, ``"not_odd"`` (a subset or strain window
    of even width), ``"subset_too_large"``, ``"shape_mismatch"`` (ROI, brush or
    image sizes differ), ``"seed_outside_roi"``, ``"no_seed_match"``.
    """

    def __init__(self, code: str, message: str, **fields: Any):
        super().__init__(message)
        self.code = code
        self.fields = fields
