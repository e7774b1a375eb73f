"""One copy of how fields are shown: titles, labels with units, colour maps and limits.

The figures, the PNG/GIF/MP4 renderings and the PDF report all take their
field titles, axis and colour-bar labels and colour limits from here, so a
field looks and reads the same everywhere. Field names, their titles and the
kind of quantity they are (which picks the unit) are
:data:`~napari_aldic.engine.io.columns.FIELD_INFO`.

Nothing here imports matplotlib at module level.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core.reasons import REASONS, Reason
from ..core.units import Units
from ..io.columns import FIELD_INFO, unit_of

__all__ = ["colour_limits", "field_colour_limits", "field_title", "field_label",
           "check_field", "unknown_field", "needs_strain", "frame_title", "label_axes",
           "transparent_cmap", "DIVERGING", "SEQUENTIAL", "REASON_COLOURS", "reason_colour"]

#: colour map of signed fields whose limits straddle zero
DIVERGING = "RdBu_r"
#: colour map of everything else (magnitudes, ZNCC, one-signed fields)
SEQUENTIAL = "viridis"
#: kinds of quantity computed from the strain (need ``strain=True``)
STRAIN_KINDS = ("strain", "angle", "rate")
#: kinds of quantity that can take both signs (drawn with :data:`DIVERGING`)
SIGNED_KINDS = ("length", "velocity", "strain", "angle", "rate")
#: fields of a signed kind that are never negative
NON_NEGATIVE_FIELDS = ("magnitude", "von_mises", "max_shear")
_LIMIT_MODES = ("range", "symmetric", "from_zero")
#: the colour of each reason code (from the one reason table, core.reasons.REASONS)
REASON_COLOURS = {int(code): info.colour for code, info in REASONS.items()}


def reason_colour(code: int) -> str:
    """The colour of reason ``code`` in every figure (black for an unknown code)."""
    return Reason.colour(code)


# =================================================================== names
def unknown_field(name: str) -> ValueError:
    """The error for a field name that is not in :data:`FIELD_INFO` (names the choices)."""
    return ValueError(f"unknown field {name!r}; choose one of {sorted(FIELD_INFO)}")


def check_field(name: str) -> None:
    """Raise :func:`unknown_field` when ``name`` is no field of :data:`FIELD_INFO`."""
    if name not in FIELD_INFO:
        raise unknown_field(name)


def field_title(name: str) -> str:
    """Human title of a field, e.g. ``"u (x displacement)"``."""
    return FIELD_INFO[name][0]


def needs_strain(name: str) -> bool:
    """True for the fields computed from the strain (strains, rotation, rates)."""
    return FIELD_INFO.get(name, ("", ""))[1] in STRAIN_KINDS


def field_label(name: str, units: Units, info: dict | None = None) -> str:
    """Colour-bar / axis label of a field with its unit, e.g. ``"u (µm)"``.

    Strains name their measure when ``info["strain"]`` (from
    :func:`~napari_aldic.engine.io.collect_frames`) gives it.
    """
    check_field(name)
    kind = FIELD_INFO[name][1]
    unit = unit_of(kind, units)
    if kind == "strain":
        s = (info or {}).get("strain") or {}
        measure = s.get("measure", "").replace("_", "-")
        return f"{name} ({measure}, dimensionless)" if measure else f"{name} (dimensionless)"
    if kind == "rate":
        return f"{name} ({unit})"
    return f"{name} ({unit})" if unit else name


def frame_title(fr, units: Units) -> str:
    """``"frame k"``, with its time when ``units`` has a frame interval."""
    t = f"frame {fr.index}"
    if units.has_time:
        t += f", t = {units.time(fr.index):g} {units.time_unit}"
    return t


def label_axes(ax, unit: str) -> None:
    """Label the image axes of a map: ``x (unit)`` and ``y (unit)``."""
    ax.set_xlabel(f"x ({unit})")
    ax.set_ylabel(f"y ({unit})")


def transparent_cmap(name: str):
    """The matplotlib colour map ``name`` drawing NaN (no trusted node) transparent."""
    import matplotlib

    return matplotlib.colormaps[name].with_extremes(bad=(0, 0, 0, 0))


# =================================================================== limits
def _finite(values) -> np.ndarray:
    if isinstance(values, np.ndarray):
        allv = np.ravel(values)
    else:
        allv = np.concatenate([np.ravel(v) for v in values]) if len(values) else np.empty(0)
    return allv[np.isfinite(allv)]


def colour_limits(values, mode: str = "range", *, percentile: float = 99.5,
                  fallback: float = 1e-9) -> tuple[float, float]:
    """Colour limits ``(lo, hi)`` of the finite entries of ``values``.

    Parameters
    ----------
    values : array or sequence of arrays
        Values to cover, e.g. one array per frame so that every frame shares
        the limits; NaN and infinite entries are ignored.
    mode : {"range", "symmetric", "from_zero"}
        ``"range"``: the ``100 - percentile`` and ``percentile`` percentiles,
        as they are (equal when the values are). ``"symmetric"``: ``(-m, m)``
        with ``m`` the ``percentile`` of ``|values|``. ``"from_zero"``:
        ``(0, hi)`` with ``hi`` the ``percentile`` of the values. In the last
        two, a limit that comes out ``<= 0`` is replaced by the largest
        (absolute) value, or by ``fallback`` when that is smaller.
    percentile : float
        Robust upper percentile; ``100`` takes the extreme values.
    fallback : float
        Upper limit when every value is 0 (``"symmetric"``/``"from_zero"``).

    Returns
    -------
    (lo, hi) : floats; ``(-1, 1)`` (``"symmetric"``) or ``(0, 1)`` without any
    finite value.
    """
    if mode not in _LIMIT_MODES:
        raise ValueError(f"mode={mode!r}; choose one of {_LIMIT_MODES}")
    finite = _finite(values)
    if finite.size == 0:
        return (-1.0, 1.0) if mode == "symmetric" else (0.0, 1.0)
    if mode == "range":
        return (float(np.percentile(finite, 100.0 - percentile)),
                float(np.percentile(finite, percentile)))
    if mode == "symmetric":
        finite = np.abs(finite)
    top = float(finite.max()) if percentile >= 100 else float(np.percentile(finite, percentile))
    if not top > 0:
        top = max(float(finite.max()), fallback)
    return (-top, top) if mode == "symmetric" else (0.0, top)


def field_colour_limits(name: str, values: Sequence[np.ndarray],
                        clim=None) -> tuple[str, float, float]:
    """``(colour map name, vmin, vmax)`` of field ``name`` shared by all frames of
    an export.

    ``clim = (vmin, vmax)`` fixes the limits; otherwise they are the robust
    range of ``values`` (:func:`colour_limits`, 0.5 to 99.5 %). Signed
    fields whose limits straddle zero get :data:`DIVERGING` with limits made
    symmetric (unless ``clim`` is given); ZNCC is drawn from at most 0.99 up
    to 1; an empty range is widened by 1 % so the colour bar stays readable.
    """
    kind = FIELD_INFO[name][1]
    if clim is not None:
        lo, hi = float(clim[0]), float(clim[1])
    else:
        lo, hi = colour_limits(values)
    if name == "zncc":
        return SEQUENTIAL, (min(lo, 0.99) if clim is None else lo), (1.0 if clim is None else hi)
    signed = kind in SIGNED_KINDS and name not in NON_NEGATIVE_FIELDS
    if signed and lo < 0 < hi:
        if clim is None:
            lim = max(abs(lo), abs(hi))
            lo, hi = -lim, lim
        return DIVERGING, lo, hi
    if hi <= lo:
        span = abs(lo) * 0.01 or 1e-6
        lo, hi = lo - span, hi + span
    return SEQUENTIAL, lo, hi
