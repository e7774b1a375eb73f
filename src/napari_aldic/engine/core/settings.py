"""The analysis settings: parameters, units, strain and tracking in one type.

A settings file (written by ``napari-aldic params``, ``run --params-out``, the
widget's "Save parameters" or :func:`~napari_aldic.engine.write_settings`) is the
JSON form of :class:`Settings`::

    {"format": "napari-aldic-settings", "format_version": 1,
     "software": "napari-aldic 0.1.0",
     "params": {DICParams fields},
     "units": {"pixel_size": 0.05, "unit": "um", "frame_interval": 2.0, "time_unit": "s"},
     "strain": {"window": 5, "method": "plane_fit", "measure": "green_lagrange"},
     "tracking": {"reference": "accumulative", "start": 0, "stop": null, "stride": 1}}

``units``, ``strain`` and ``tracking`` are optional, and so is every key of the
``strain`` and ``tracking`` sections: a key that is not given is left to the
reader (the widget keeps its control, an export uses :data:`STRAIN_DEFAULTS`).
The older form, a plain JSON object of DICParams fields, is read too.
Every section is checked here, once, by :class:`Settings` itself.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from .params import DICParams, StrainParams
from .reasons import DICError
from .units import Units
from .version import __version__

__all__ = ["Settings", "SETTINGS_FORMAT", "STRAIN_DEFAULTS", "STRAIN_METHODS",
           "STRAIN_MEASURES", "REFERENCE_MODES"]

SETTINGS_FORMAT = "napari-aldic-settings"
SETTINGS_FORMAT_VERSION = 1
#: top-level keys of a settings document
SECTIONS = ("format", "format_version", "software", "params", "units", "strain", "tracking",
            "probes")
#: the probe-set document format (written by ``engine.probes.ProbeSet.to_dict``)
PROBES_FORMAT = "napari-aldic-probes"
STRAIN_METHODS = ("plane_fit", "fem")
STRAIN_MEASURES = ("green_lagrange", "infinitesimal", "euler_almansi")
#: strain settings used where a file or a caller gives none
STRAIN_DEFAULTS = StrainParams().to_dict()
REFERENCE_MODES = ("accumulative", "incremental")
TRACKING_KEYS = ("reference", "start", "stop", "stride")


@dataclass(frozen=True)
class Settings:
    """The complete settings of an analysis, validated on construction.

    Attributes
    ----------
    params : DICParams
        The correlation parameters (a dict of DICParams fields is converted).
    units : Units or None
        Pixel size and frame interval (a dict is converted); None: not given.
    strain : dict or None
        Strain settings, any of ``window`` (odd number of nodes >= 3),
        ``method`` (:data:`STRAIN_METHODS`) and ``measure``
        (:data:`STRAIN_MEASURES`); None: not given. :meth:`strain_options`
        fills in :data:`STRAIN_DEFAULTS`.
    tracking : dict or None
        Tracking settings of a stack, any of ``reference``
        (:data:`REFERENCE_MODES`), ``start`` (first frame, >= 0), ``stop``
        (last frame, >= 1, after ``start``; None: the last frame of the stack)
        and ``stride`` (>= 1); None: not given.
    probes : dict or None
        A probe set (``ProbeSet.to_dict()`` of :mod:`napari_aldic.engine.probes`:
        ``{"format": "napari-aldic-probes", "probes": [...]}``), kept as given;
        its geometry is checked when it is read by ``ProbeSet.from_dict``.

    Raises
    ------
    ValueError
        For any invalid value or unknown key, with a message naming it.
    """

    params: DICParams = field(default_factory=DICParams)
    units: Units | None = None
    strain: dict | None = None
    tracking: dict | None = None
    probes: dict | None = None

    def __post_init__(self) -> None:
        params = self.params
        if isinstance(params, dict):
            params = _params_from_dict(params)
        elif not isinstance(params, DICParams):
            raise ValueError(f"params must be a DICParams or a dict of its fields, not "
                             f"{type(params).__name__}")
        units = self.units
        if isinstance(units, dict):
            units = Units.from_dict(units) if units else None
        elif units is not None and not isinstance(units, Units):
            raise ValueError("the 'units' section must be a JSON object with pixel_size, "
                             "unit, frame_interval, time_unit")
        object.__setattr__(self, "params", params)
        object.__setattr__(self, "units", units)
        object.__setattr__(self, "strain", _strain_section(self.strain))
        object.__setattr__(self, "tracking", _tracking_section(self.tracking))
        object.__setattr__(self, "probes", _probes_section(self.probes))

    # ------------------------------------------------------------ views
    def strain_options(self) -> dict[str, Any]:
        """``window``, ``method`` and ``measure``: the given strain settings
        over :data:`STRAIN_DEFAULTS` (``compute_strain`` keywords)."""
        return {**STRAIN_DEFAULTS, **(self.strain or {})}

    @property
    def reference(self) -> str:
        """The tracking reference mode (``"accumulative"`` when not given)."""
        return (self.tracking or {}).get("reference", REFERENCE_MODES[0])

    def replace(self, **changes: Any) -> Settings:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------ JSON
    def to_dict(self) -> dict[str, Any]:
        """The settings document (plain JSON); a strain section is written
        complete (missing keys from :data:`STRAIN_DEFAULTS`)."""
        doc: dict[str, Any] = {"format": SETTINGS_FORMAT,
                               "format_version": SETTINGS_FORMAT_VERSION,
                               "software": f"napari-aldic {__version__}",
                               "params": self.params.to_dict()}
        if self.units is not None:
            doc["units"] = self.units.to_dict()
        if self.strain is not None:
            doc["strain"] = self.strain_options()
        if self.tracking is not None:
            doc["tracking"] = dict(self.tracking)
        if self.probes is not None:
            doc["probes"] = dict(self.probes)
        return doc

    @classmethod
    def from_dict(cls, doc) -> Settings:
        """Settings from a settings document, or from a plain object of
        DICParams fields (the older parameter file: no other sections).

        Unknown sections, unknown keys and invalid values raise ``ValueError``.
        """
        if not isinstance(doc, dict):
            raise ValueError("settings must be a JSON object (a settings document or "
                             "DICParams fields)")
        if doc.get("format") != SETTINGS_FORMAT and not isinstance(doc.get("params"), dict):
            return cls(params=_params_from_dict(doc))
        unknown = sorted(set(doc) - set(SECTIONS))
        if unknown:
            raise ValueError(f"unknown section(s) {unknown}; valid sections are "
                             f"{sorted(SECTIONS)}")
        params = doc.get("params")
        return cls(params=_params_from_dict({} if params is None else params),
                   units=doc.get("units"), strain=doc.get("strain"),
                   tracking=doc.get("tracking"), probes=doc.get("probes"))


# ------------------------------------------------------------------ checks
def _params_from_dict(d: dict) -> DICParams:
    try:
        return DICParams.from_dict(d)
    except TypeError as exc:  # e.g. a wrongly typed field
        raise ValueError(str(exc)) from None


def _section(value, name: str, keys: tuple[str, ...]) -> dict | None:
    """A copy of a settings section (None stays None), unknown keys rejected."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise ValueError(f"the '{name}' section must be a JSON object with "
                         f"{', '.join(keys)}")
    unknown = sorted(set(value) - set(keys))
    if unknown:
        raise ValueError(f"unknown {name} setting(s) {unknown}; valid names are "
                         f"{', '.join(keys)}")
    return dict(value)


def _whole(value, what: str, lowest: int) -> int:
    """``value`` as an int (whole floats such as 5.0 pass) >= ``lowest``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            (isinstance(value, float) and not value.is_integer()):
        raise ValueError(f"{what} {value!r} must be a whole number")
    if value < lowest:
        raise ValueError(f"{what} {int(value)} must be >= {lowest}")
    return int(value)


def _choice(value, what: str, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise ValueError(f"{what} {value!r} must be one of {', '.join(choices)}")
    return value


def _strain_section(value) -> dict | None:
    strain = _section(value, "strain", tuple(STRAIN_DEFAULTS))
    if strain is None:
        return None
    if "window" in strain:
        strain["window"] = _whole(strain["window"], "strain window", 3)
        if strain["window"] % 2 == 0:
            raise DICError("not_odd", f"strain window {strain['window']} must be an odd "
                           "number of nodes >= 3 (e.g. 5)", name="window",
                           value=strain["window"])
    if "method" in strain:
        _choice(strain["method"], "strain method", STRAIN_METHODS)
    if "measure" in strain:
        _choice(strain["measure"], "strain measure", STRAIN_MEASURES)
    return strain


def _tracking_section(value) -> dict | None:
    tracking = _section(value, "tracking", TRACKING_KEYS)
    if tracking is None:
        return None
    if "reference" in tracking:
        _choice(tracking["reference"], "tracking reference", REFERENCE_MODES)
    if "stride" in tracking:
        tracking["stride"] = _whole(tracking["stride"], "frame stride", 1)
    start, stop = tracking.get("start"), tracking.get("stop")
    if start is not None:
        tracking["start"] = start = _whole(start, "first frame", 0)
    if stop is not None:
        tracking["stop"] = stop = _whole(stop, "last frame", 1)
    if start is not None and stop is not None and not start < stop:
        raise ValueError(f"the first frame ({start}) must come before the last frame ({stop})")
    return tracking


def _probes_section(value) -> dict | None:
    # the probes layer (engine.probes) sits above core: only the envelope is checked here
    if value is None:
        return None
    if not isinstance(value, dict) or value.get("format") != PROBES_FORMAT \
            or not isinstance(value.get("probes"), list):
        raise ValueError(f"the 'probes' section must be a JSON object with format "
                         f"{PROBES_FORMAT!r} and a 'probes' list (a probe set)")
    return value
