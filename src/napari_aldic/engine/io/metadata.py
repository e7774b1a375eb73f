"""Physical pixel size and frame interval recorded by instruments in image files.

Read from what tifffile already parses (``ome_metadata``, ``imagej_metadata``,
``fei_metadata``, ``sem_metadata``, the resolution tags) and from OME-Zarr
``multiscales`` scales, in this order of trust:

* OME-XML ``Pixels``: ``PhysicalSizeX`` (+ unit) and ``TimeIncrement`` (+ unit);
* ImageJ: ``unit`` with the XResolution tag, ``finterval`` (seconds, or ``tunit``);
* FEI / Thermo Fisher SEM: ``Scan/PixelWidth`` (metres);
* Zeiss SEM: ``ap_image_pixel_size`` (value and unit);
* TIFF resolution tags in centimetres (or inches other than the screen values
  72/96 dpi that programs write by default).

Each value records where it came from (``source``), which runs keep in their
metadata (``meta["units_source"]``) so a reader of the results can tell a
measured pixel size from a typed one. ome-types is not needed: the OME
``Pixels`` attributes are the only part used.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass

__all__ = ["PixelSize", "FrameInterval", "tiff_pixel_size", "tiff_frame_interval",
           "ome_zarr_pixel_size", "ome_zarr_frame_interval", "units_of"]

#: length units, normalised, and their size in metres
_UNITS = {"nm": 1e-9, "um": 1e-6, "mm": 1e-3, "cm": 1e-2, "m": 1.0}
_ALIASES = {"nanometer": "nm", "nanometre": "nm", "micron": "um", "microns": "um",
            "micrometer": "um", "micrometre": "um", "µm": "um", "μm": "um", "\\u00b5m": "um",
            "millimeter": "mm", "millimetre": "mm", "centimeter": "cm", "centimetre": "cm",
            "meter": "m", "metre": "m"}
#: time units, normalised
_TIME = {"s": "s", "sec": "s", "second": "s", "seconds": "s", "ms": "ms", "millisecond": "ms",
         "milliseconds": "ms", "us": "us", "µs": "us", "microsecond": "us", "min": "min",
         "minute": "min", "minutes": "min", "h": "h", "hour": "h", "hours": "h"}
#: resolutions (dots per inch) that programs write by default: not a measurement
_SCREEN_DPI = (1.0, 72.0, 96.0)


@dataclass(frozen=True)
class PixelSize:
    """Length of one pixel found in a file's metadata: ``value`` in ``unit``
    (nm, um, mm, cm or m), and where it came from (``source``)."""

    value: float
    unit: str
    source: str

    @classmethod
    def make(cls, value, unit, source: str) -> PixelSize | None:
        """A pixel size in a known unit, tidied (m -> nm or um), or None."""
        try:
            value = float(value)
        except (TypeError, ValueError):
            return None
        name = _ALIASES.get(str(unit).strip().lower(), str(unit).strip().lower())
        if name not in _UNITS or not (math.isfinite(value) and value > 0):
            return None
        metres = value * _UNITS[name]
        if name in ("m", "cm"):  # SEM tags are in metres: say nm or um
            name = "nm" if metres < 1e-6 else ("um" if metres < 1e-3 else "mm")
            value = metres / _UNITS[name]
        return cls(float(f"{value:.12g}"), name, source)


@dataclass(frozen=True)
class FrameInterval:
    """Time between frames found in a file's metadata: ``value`` in ``unit``
    (s, ms, us, min or h), and where it came from (``source``)."""

    value: float
    unit: str
    source: str

    @classmethod
    def make(cls, value, unit, source: str) -> FrameInterval | None:
        try:
            value = float(value)
        except (TypeError, ValueError):
            return None
        name = _TIME.get(str(unit or "s").strip().lower())
        if name is None or not (math.isfinite(value) and value > 0):
            return None
        return cls(float(f"{value:.12g}"), name, source)


# ------------------------------------------------------------------ TIFF
def _first(readers, tf):
    for reader in readers:
        try:
            found = reader(tf)
        except Exception:  # odd metadata must not stop reading the pixels
            found = None
        if found is not None:
            return found
    return None


def tiff_pixel_size(tf) -> PixelSize | None:
    """The pixel size in an open ``tifffile.TiffFile``'s metadata, or None."""
    return _first((_ome_xml_size, _imagej_size, _fei_size, _sem_size, _resolution_size), tf)


def tiff_frame_interval(tf) -> FrameInterval | None:
    """The frame interval in an open ``tifffile.TiffFile``'s metadata, or None."""
    return _first((_ome_xml_interval, _imagej_interval), tf)


def _ome_pixels(tf):
    xml = tf.ome_metadata
    if not xml:
        return None
    for el in ET.fromstring(xml).iter():
        if el.tag.endswith("}Pixels") or el.tag == "Pixels":
            return el.attrib
    return None


def _ome_xml_size(tf) -> PixelSize | None:
    px = _ome_pixels(tf)
    if not px or "PhysicalSizeX" not in px:
        return None
    return PixelSize.make(px["PhysicalSizeX"], px.get("PhysicalSizeXUnit", "um"), "OME-XML")


def _ome_xml_interval(tf) -> FrameInterval | None:
    px = _ome_pixels(tf)
    if not px or "TimeIncrement" not in px:
        return None
    return FrameInterval.make(px["TimeIncrement"], px.get("TimeIncrementUnit", "s"), "OME-XML")


def _resolution(page) -> float | None:
    tag = page.tags.get("XResolution")
    if tag is None:
        return None
    num, den = tag.value
    return num / den if den else None


def _imagej_size(tf) -> PixelSize | None:
    meta = tf.imagej_metadata
    if not meta or "unit" not in meta:
        return None
    res = _resolution(tf.pages[0])
    if not res:
        return None
    return PixelSize.make(1.0 / res, meta["unit"], "ImageJ")


def _imagej_interval(tf) -> FrameInterval | None:
    meta = tf.imagej_metadata
    if not meta or not meta.get("finterval"):
        return None
    return FrameInterval.make(meta["finterval"], meta.get("tunit", "s"), "ImageJ")


def _fei_size(tf) -> PixelSize | None:
    meta = tf.fei_metadata
    if not meta:
        return None
    for section in ("Scan", "EScan", "IScan"):
        width = (meta.get(section) or {}).get("PixelWidth")
        if width:
            return PixelSize.make(width, "m", "FEI SEM")
    return None


def _sem_size(tf) -> PixelSize | None:
    meta = tf.sem_metadata
    if not meta:
        return None
    for key, val in meta.items():
        if "pixel_size" in str(key).lower() and isinstance(val, tuple) and len(val) >= 3:
            return PixelSize.make(val[1], val[2], "Zeiss SEM")
    return None


def _resolution_size(tf) -> PixelSize | None:
    page = tf.pages[0]
    res = _resolution(page)
    unit = page.tags.get("ResolutionUnit")
    unit = int(unit.value) if unit is not None else 2
    if not res or unit not in (2, 3):
        return None
    if unit == 2 and any(abs(res - d) < 1e-9 for d in _SCREEN_DPI):
        return None
    return PixelSize.make((2.54 if unit == 2 else 1.0) / res, "cm", "TIFF resolution")


# ------------------------------------------------------------------ OME-Zarr
def _ome_zarr_axis(ms: dict, level0: dict, names: tuple[str, ...]):
    """(scale, unit) of the first of axes ``names`` at OME-Zarr level 0, or None."""
    axes = ms.get("axes") or []
    scale = next((t.get("scale") for t in level0.get("coordinateTransformations", [])
                  if t.get("type") == "scale"), None)
    if not scale or not axes or len(scale) != len(axes):
        return None
    labels = [a.get("name") if isinstance(a, dict) else a for a in axes]
    for name in names:
        if name in labels:
            ax = axes[labels.index(name)]
            unit = ax.get("unit") if isinstance(ax, dict) else None
            return (scale[labels.index(name)], re.sub(r"\s", "", unit)) if unit else None
    return None


def ome_zarr_pixel_size(ms: dict, level0: dict) -> PixelSize | None:
    """Pixel size of OME-Zarr level 0: its x scale in the x axis' unit."""
    found = _ome_zarr_axis(ms, level0, ("x",))
    return PixelSize.make(*found, "OME-Zarr") if found else None


def ome_zarr_frame_interval(ms: dict, level0: dict) -> FrameInterval | None:
    """Frame interval of OME-Zarr level 0: its t scale in the t axis' unit."""
    found = _ome_zarr_axis(ms, level0, ("t",))
    if not found:
        return None
    unit = {"second": "s", "millisecond": "ms", "microsecond": "us", "minute": "min",
            "hour": "h"}.get(found[1], found[1])
    return FrameInterval.make(found[0], unit, "OME-Zarr")


# ------------------------------------------------------------------ both
def units_of(pixel_size: PixelSize | None, interval: FrameInterval | None, name: str = ""):
    """``(Units, source)`` from what a file records, or ``(None, {})`` when it
    records neither: ``source`` names where each value came from, e.g.
    ``{"pixel_size": "ImageJ metadata of stack.tif", "frame_interval": ...}``."""
    from ..core.units import Units

    if pixel_size is None and interval is None:
        return None, {}
    of = f" metadata of {name}" if name else " metadata"
    units = Units(pixel_size=pixel_size.value if pixel_size else 1.0,
                  unit=pixel_size.unit if pixel_size else "px",
                  frame_interval=interval.value if interval else None,
                  time_unit=interval.unit if interval else "s")
    source = {}
    if pixel_size is not None:
        source["pixel_size"] = pixel_size.source + of
    if interval is not None:
        source["frame_interval"] = interval.source + of
    return units, source
