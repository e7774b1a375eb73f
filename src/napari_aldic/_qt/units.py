"""The Units panel: pixel size and frame interval, applied to the layers.

The pixel size and frame interval set the scale (and the units) of the
image, its input layers and every result layer; the values of u, v and |u|
are shown in the length unit.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
from magicgui.widgets import ComboBox, FloatSpinBox
from psygnal import Signal

from ..engine import Units
from ..i18n import tr
from .controls import Panel, Plan, put

__all__ = ["UnitsPanel", "LENGTH_UNITS", "TIME_UNITS"]

#: length units offered -> the unit name napari (pint) is given
LENGTH_UNITS = {"px": "pixel", "nm": "nm", "µm": "µm", "mm": "mm", "cm": "cm", "m": "m"}
#: time units offered -> the unit name napari (pint) is given
TIME_UNITS = {"frame": "pixel", "ms": "ms", "s": "s", "min": "min", "h": "h"}
# other spellings of the units accepted in a parameter file
_LENGTH_ALIASES = {"pixel": "px", "pixels": "px", "um": "µm", "\u03bcm": "µm", "micron": "µm",
                   "microns": "µm", "micrometer": "µm", "micrometre": "µm",
                   "nanometer": "nm", "nanometre": "nm", "millimeter": "mm",
                   "millimetre": "mm", "centimeter": "cm", "centimetre": "cm",
                   "meter": "m", "metre": "m"}
_TIME_ALIASES = {"frames": "frame", "sec": "s", "second": "s", "seconds": "s",
                 "millisecond": "ms", "milliseconds": "ms", "minute": "min",
                 "minutes": "min", "hour": "h", "hours": "h"}
# napari's (pint's) names of the layer units -> the panel's names
_LAYER_LENGTH = {"pixel": "px", "micrometer": "µm", "nanometer": "nm", "millimeter": "mm",
                 "centimeter": "cm", "meter": "m"}
_LAYER_TIME = {"pixel": "frame", "second": "s", "millisecond": "ms", "minute": "min",
               "hour": "h"}


def unit_name(name, known: dict, aliases: dict, what: str) -> str:
    """The panel's spelling of a unit name from a file."""
    if isinstance(name, str):
        if name in known:
            return name
        alias = aliases.get(name.strip().lower(), aliases.get(name.strip()))
        if alias is not None:
            return alias
    raise ValueError(tr("{what} {name!r} is not one the widget offers ({join})").format(
                            what=what, name=name, join=', '.join(known)))


def _set_units(layer, units: list[str], length: str, time: str) -> None:
    """``layer``'s units with the last two axes in ``length`` and a third-last
    (time) axis in ``time``; unknown units for pint keep the old ones."""
    units[-2:] = [length, length]
    if layer.ndim >= 3:
        units[-3] = time
    try:
        layer.units = units
    except Exception:  # unknown unit for pint: keep the scale only
        pass


class UnitsPanel(Panel):
    """Pixel size, length unit, frame interval and time unit.

    Signals
    -------
    units_changed
        The user changed a unit control (not while the panel follows an image
        or a settings file is applied): apply them to the layers.
    """

    units_changed = Signal()

    def __init__(self):
        self._syncing = False
        self._applied: tuple[float, float] | None = None  # (pixel size, interval) applied
        super().__init__()

    def _setup_ui(self) -> None:
        self.pixel_size = FloatSpinBox(label=tr("Pixel size"), value=1.0, min=0.0001, max=1e6,
                                       step=0.0001,
                                       tooltip=tr("Physical size of one image pixel; sets the "
                                               "scale of the image, its ROI layers and every "
                                               "result layer, and the unit of u, v, |u|."))
        self.unit = ComboBox(label=tr("Length unit"), value="px", choices=list(LENGTH_UNITS),
                             tooltip=tr("Unit of the pixel size."))
        self.frame_interval = FloatSpinBox(label=tr("Frame interval"), value=1.0, min=0.0001,
                                           max=1e9, step=0.0001,
                                           tooltip=tr("Time between frames (time-axis scale)."))
        self.time_unit = ComboBox(label=tr("Time unit"), value="frame",
                                  choices=[(tr("frame") if t == "frame" else t, t)
                                           for t in TIME_UNITS],
                                  tooltip=tr("Unit of the frame interval."))
        self.extend([self.pixel_size, self.unit, self.frame_interval,
                     self.time_unit])

    def _setup_callbacks(self) -> None:
        for w in (self.pixel_size, self.unit, self.frame_interval, self.time_unit):
            w.changed.connect(self._on_control)

    def _on_control(self, *_) -> None:
        if not self._syncing:
            self.units_changed.emit()

    @contextmanager
    def quiet(self):
        """Change controls without :attr:`units_changed` (applied once, afterwards)."""
        self._syncing = True
        try:
            yield
        finally:
            self._syncing = False

    # ------------------------------------------------------------ state
    @property
    def values(self) -> tuple:
        """(pixel size, length unit, frame interval, time unit) of the controls."""
        return (self.pixel_size.value, self.unit.value, self.frame_interval.value,
                self.time_unit.value)

    @property
    def length(self) -> tuple[float, str]:
        """(pixel size, length unit)."""
        return float(self.pixel_size.value), self.unit.value

    @property
    def time(self) -> tuple[float | None, str]:
        """(frame interval, time unit); the interval is ``None`` for frame numbers."""
        frames = self.time_unit.value == "frame"
        return (None if frames else float(self.frame_interval.value)), self.time_unit.value

    @property
    def units(self) -> Units:
        """The engine :class:`Units` of the controls (``ValueError`` for a pixel
        size other than 1 in 'px')."""
        ps, unit = self.length
        if unit == "px" and ps != 1.0:
            raise ValueError(tr("the pixel size is {ps:g} with the length unit 'px': choose "
                                "the physical unit of the pixel size (e.g. µm), or set the "
                                "pixel size to 1").format(ps=ps))
        dt, t_unit = self.time
        return Units(ps, unit) if dt is None else Units(ps, unit, dt, t_unit)

    def summary(self) -> str:
        """The units in words (for the log)."""
        if self.time_unit.value == "frame":
            return tr("pixel size {pixel_size:g} {unit}, frame numbers").format(
                pixel_size=self.pixel_size.value, unit=self.unit.value)
        return tr("pixel size {pixel_size:g} {unit}, frame interval {interval:g} "
                  "{time_unit}").format(pixel_size=self.pixel_size.value, unit=self.unit.value,
                                        interval=self.frame_interval.value,
                                        time_unit=self.time_unit.value)

    # ------------------------------------------------------------ layers
    def read_image(self, img) -> None:
        """Show the units of image layer ``img`` (its scale is taken as applied)."""
        with self.quiet():
            self.pixel_size.value = float(img.scale[-1])
            unit = str(img.units[-1])
            inv = {v: k for k, v in LENGTH_UNITS.items()}
            self.unit.value = inv.get(unit, _LAYER_LENGTH.get(unit, "px"))
            if img.ndim == 3:
                self.frame_interval.value = float(img.scale[0])
                self.time_unit.value = _LAYER_TIME.get(str(img.units[0]), "frame")
        self._applied = (self.pixel_size.value, self.frame_interval.value)

    def apply_to(self, inputs: list, results: list) -> None:
        """Rescale the ``inputs`` layers (image, ROI ...) from the units applied
        last to the controls' ones, and give every layer the unit names
        (``results`` are rebuilt afterwards; only their unit names change here)."""
        p, dt = float(self.pixel_size.value), float(self.frame_interval.value)
        old_p, old_dt = self._applied or (1.0, 1.0)
        unit, t_unit = LENGTH_UNITS[self.unit.value], TIME_UNITS[self.time_unit.value]
        for lay in inputs:
            scale = np.array(lay.scale, float)
            translate = np.array(lay.translate, float)
            scale[-2:] = scale[-2:] * (p / old_p)
            translate[-2:] = translate[-2:] * (p / old_p)
            if lay.ndim >= 3:
                scale[-3] = scale[-3] * (dt / old_dt)
                translate[-3] = translate[-3] * (dt / old_dt)
            lay.scale = scale
            lay.translate = translate
            _set_units(lay, [str(u) for u in lay.units], unit, t_unit)
        for lay in results:
            _set_units(lay, [str(u) for u in lay.units], unit, t_unit)
        self._applied = (p, dt)

    # ------------------------------------------------------------ settings files
    def units_plan(self, units: Units, plan: Plan) -> None:
        """Add the controls for ``units`` (from a settings file) to ``plan``."""
        unit = unit_name(units.unit, LENGTH_UNITS, _LENGTH_ALIASES, tr("length unit"))
        put(plan, self.unit, unit, tr("length unit"))
        put(plan, self.pixel_size, units.pixel_size, tr("pixel size"))
        if units.frame_interval is None:
            put(plan, self.time_unit, "frame", tr("time unit"))
            put(plan, self.frame_interval, 1.0, tr("frame interval"))
        else:
            t_unit = unit_name(units.time_unit, TIME_UNITS, _TIME_ALIASES, tr("time unit"))
            put(plan, self.time_unit, t_unit, tr("time unit"))
            put(plan, self.frame_interval, units.frame_interval, tr("frame interval"))
