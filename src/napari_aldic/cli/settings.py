"""Settings from a settings file (``--params`` / ``--settings``) with the
command-line options applied; every check is :class:`~napari_aldic.engine.Settings`'s."""

from __future__ import annotations

from ..engine import Settings, Units
from ..engine.io import read_settings
from .parser import OVERRIDES

UNIT_OPTIONS = ("pixel_size", "unit", "frame_interval", "time_unit")
#: strain option (dest) -> key of the settings' strain section
STRAIN_OPTIONS = {"strain_window": "window", "strain_method": "method",
                  "strain_measure": "measure"}


def _given(args, names) -> dict:
    """The options of ``names`` given on the command line (not None)."""
    return {k: getattr(args, k) for k in names if getattr(args, k, None) is not None}


def settings_file(path) -> Settings:
    """The settings of the file ``path``; the defaults when ``path`` is None."""
    return Settings() if path is None else read_settings(path)


def settings_from_args(args, path) -> Settings:
    """The settings file ``path`` (the defaults when None) with the options of
    ``args`` that are given applied over it: DICParams fields (``OVERRIDES``),
    units and strain settings."""
    base = settings_file(path)
    changes = _given(args, OVERRIDES)
    params = base.params.replace(**changes) if changes else base.params
    strain = base.strain
    given = {STRAIN_OPTIONS[k]: v for k, v in _given(args, STRAIN_OPTIONS).items()}
    if given:
        strain = {**(strain or {}), **given}
    return base.replace(params=params, units=units_from_args(args, base.units), strain=strain)


def units_from_args(args, base: Units | None = None) -> Units | None:
    """Units from --pixel-size/--unit/--frame-interval/--time-unit over ``base``
    (``base`` when none is given)."""
    given = _given(args, UNIT_OPTIONS)
    if not given:
        return base
    return Units.from_dict({**(base.to_dict() if base is not None else {}), **given})
