"""Reason codes explaining why a node is (or is not) trusted."""

from __future__ import annotations

from enum import IntEnum

__all__ = ["Reason"]


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
        """Human-readable text of a reason code."""
        return {
            0: "converged",
            1: "subset component too small (mask)",
            2: "not converged (iteration cap)",
            3: "deformed subset leaves the image",
            4: "low correlation (ZNCC below threshold)",
            5: "no texture in subset",
            6: "diverged",
            7: "no initial guess",
            8: "outlier (median test)",
            9: "poor match (residual above image noise)",
            10: "motion beyond the search range",
            11: "uncertain (noise)",
            12: "global field departs from the subset match (AL-DIC)",
            13: "static feature (part of the subset does not move)",
            14: "ambiguous match (texture repeats within the search range)",
        }.get(int(code), f"unknown ({code})")
