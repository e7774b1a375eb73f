"""The main dock widget: choose layers and parameters, run DIC in a worker, show results.

The widget stays thin: it turns layers into arrays and masks (:mod:`._roi`),
runs :func:`napari_aldic._analysis.run_analysis` (the engine's ``track`` and
``compute_strain``) in a napari worker thread, and turns the results into
layers (:mod:`._layers`). Qt is reached only through magicgui and qtpy.
"""

from __future__ import annotations

import math
import os
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from magicgui.widgets import (
    CheckBox,
    ComboBox,
    Container,
    FloatSpinBox,
    Label,
    ProgressBar,
    PushButton,
    Select,
    SpinBox,
    TextEdit,
)

from ._analysis import Analysis, StrainSettings, run_analysis
from ._layers import FIELDS, LAYER_NAMES, Display, Geometry, analysis_layers, layer_name
from ._roi import build_roi, labels_mask, points_xy
from .engine import DICParams
from .engine import Units

if TYPE_CHECKING:  # pragma: no cover
    import napari

__all__ = ["DICWidget"]

_SUBTRACT_WORDS = ("hole", "crack", "mask", "exclude", "subtract", "notch", "cut")
_LENGTH_UNITS = {"px": "pixel", "nm": "nm", "µm": "µm", "mm": "mm", "cm": "cm", "m": "m"}
_TIME_UNITS = {"frame": "pixel", "ms": "ms", "s": "s", "min": "min", "h": "h"}
# other spellings of the units accepted in a parameter file
_LENGTH_ALIASES = {"pixel": "px", "pixels": "px", "um": "µm", "\u03bcm": "µm", "micron": "µm",
                   "microns": "µm", "micrometer": "µm", "micrometre": "µm",
                   "nanometer": "nm", "nanometre": "nm", "millimeter": "mm",
                   "millimetre": "mm", "centimeter": "cm", "centimetre": "cm",
                   "meter": "m", "metre": "m"}
_TIME_ALIASES = {"frames": "frame", "sec": "s", "second": "s", "seconds": "s",
                 "millisecond": "ms", "milliseconds": "ms", "minute": "min",
                 "minutes": "min", "hour": "h", "hours": "h"}
#: DICParams fields that the widget shows (the others are kept from a loaded file)
_PARAM_CONTROLS = ("method", "subset", "step", "search", "refine", "init", "smooth")
_STRAIN_KEYS = ("window", "method", "measure")
_TRACKING_KEYS = ("reference", "start", "stop", "stride")


def _is_result_layer(layer) -> bool:
    return layer.name in LAYER_NAMES or "napari_aldic_analysis" in getattr(layer, "metadata", {})


def _fmt_seconds(s: float) -> str:
    s = max(0, int(round(s)))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


@dataclass
class _Job:
    """Everything a run needs, collected on the main thread."""

    stack: Any
    roi: np.ndarray | None
    params: DICParams
    reference: str
    start: int
    stop: int
    stride: int
    brush: np.ndarray | None
    strain: StrainSettings
    source: str
    summary: str


class DICWidget(Container):
    """Digital image correlation of an image stack (napari-aldic)."""

    def __init__(self, napari_viewer: "napari.viewer.Viewer"):
        super().__init__(labels=False)
        self._viewer = napari_viewer
        self._worker = None
        self._cancel = threading.Event()
        self._t0 = 0.0
        self._analysis: Analysis | None = None
        self._analysis_image = None
        self._syncing = False
        self._units_applied: tuple | None = None  # (pixel size, interval) last applied
        # DICParams fields not shown in the widget, kept from a loaded parameter file
        self._extra_params: dict[str, Any] = {}
        self._settings_dir: Path | None = None  # folder of the last parameter file
        self.running = False

        def layers_of(kind: str, optional: bool = False):
            def choices(_widget=None):
                import napari.layers as nl

                cls = getattr(nl, kind)
                out = [(lay.name, lay) for lay in self._viewer.layers
                       if isinstance(lay, cls) and not _is_result_layer(lay)]
                return ([("(none)", None)] if optional else []) + out
            return choices

        # ---- inputs
        self.image = ComboBox(label="Image stack", choices=layers_of("Image"), nullable=True,
                              tooltip="Image layer with a time axis (frames, rows, cols); the "
                                      "first frame of the range is the reference.")
        self.roi_add = Select(label="ROI (shapes)", choices=layers_of("Shapes"),
                              tooltip="Shapes layers whose rectangles, polygons and ellipses "
                                      "are analysed (union). None selected: whole image.\n"
                                      "Lines and paths in any chosen layer cut the ROI "
                                      "(cracks).")
        self.roi_subtract = Select(label="Holes (shapes)", choices=layers_of("Shapes"),
                                   tooltip="Shapes layers whose shapes are removed from the "
                                           "ROI (holes, notches, background). Layers named "
                                           "like 'hole', 'crack', 'mask' are chosen here "
                                           "automatically.")
        self.roi_labels = ComboBox(label="ROI labels", choices=layers_of("Labels", True),
                                   tooltip="Labels layer: nonzero pixels are analysed "
                                           "(intersected with the ROI shapes).")
        self.brush = ComboBox(label="Refine region", choices=layers_of("Labels", True),
                              tooltip="Labels layer painted with the brush: the mesh is "
                                      "refined where it is nonzero (quadtree).")
        self.seeds = ComboBox(label="Seeds (points)", choices=layers_of("Points", True),
                              tooltip="Points layer of seed points for the 'seed points' "
                                      "initial guess: at least one per connected ROI "
                                      "region, on well-textured material.")
        # ---- parameters
        self.method = ComboBox(label="Method", value="aldic",
                               choices=[("AL-DIC", "aldic"), ("Local (IC-GN)", "local")],
                               tooltip="AL-DIC couples the subsets to a compatible finite-"
                                       "element field (smoother, robust); Local solves every "
                                       "subset on its own (faster).")
        self.subset = SpinBox(label="Subset (px)", value=31, min=7, max=2001, step=2,
                              tooltip="Odd full width of the square correlation subset in "
                                      "pixels (31 = 31 x 31). Larger: less noise, less "
                                      "spatial resolution. It should hold ~3 speckles across.")
        self.step = SpinBox(label="Step (px)", value=8, min=1, max=1000,
                            tooltip="Node spacing in pixels.")
        self.search = SpinBox(label="Search (px)", value=20, min=1, max=100000,
                              tooltip="Initial half-range of the FFT cross-correlation "
                                      "search; it widens by itself when the peak lies on "
                                      "its border.")
        self.refine = ComboBox(label="Refinement", value="none",
                               choices=["none", "light", "medium", "strong"],
                               tooltip="Adaptive quadtree preset: light = near holes/cracks; "
                                       "medium = also the ROI outline; strong = also where "
                                       "the correlation is poor (slower).")
        self.smooth = ComboBox(label="AL-DIC smoothing", value="auto",
                               choices=[("auto (from the noise)", "auto"),
                                        ("off (plain Algorithm 1)", "off"),
                                        ("fixed length", "fixed")],
                               tooltip="Curvature regulariser of the AL-DIC global step "
                                       "(never biases uniform strain). auto: the length "
                                       "that minimises the estimated error for these "
                                       "images (~0 for clean images); off: none; fixed: "
                                       "the length below.")
        self.smooth_px = FloatSpinBox(label="Smoothing length (px)", value=10.0, min=0.5,
                                      max=10000.0, step=0.5, enabled=False,
                                      tooltip="Displacement waves shorter than ~2 pi x this "
                                              "length are damped (fixed smoothing only).")
        self.init = ComboBox(label="Initial guess", value="fft",
                             choices=[("FFT cross-correlation", "fft"),
                                      ("Seed points", "seeds")],
                             tooltip="FFT: automatic search. Seed points: propagate from the "
                                     "points of the seeds layer (large or uneven motion).")
        self.reference = ComboBox(label="Tracking", value="accumulative",
                                  choices=["accumulative", "incremental"],
                                  tooltip="accumulative: every frame against the first; "
                                          "incremental: each frame against the previous one, "
                                          "composed back to the first (large deformation).")
        self.start = SpinBox(label="First frame", value=0, min=0, max=0,
                             tooltip="Reference frame: the first frame analysed.")
        self.stop = SpinBox(label="Last frame", value=0, min=0, max=0,
                            tooltip="Last frame analysed (inclusive).")
        self.stride = SpinBox(label="Every n-th frame", value=1, min=1, max=100000,
                              tooltip="Analyse every n-th frame of the range.")
        # ---- strain
        self.strain_window = SpinBox(label="Strain window", value=5, min=3, max=101, step=2,
                                     tooltip="Odd number of nodes across the plane fit; the "
                                             "virtual strain gauge is (window - 1) * step + "
                                             "subset pixels.")
        self.strain_method = ComboBox(label="Strain method", value="plane_fit",
                                      choices=[("plane fit", "plane_fit"),
                                               ("FE gradients", "fem")],
                                      tooltip="Local least-squares plane fit over the window, "
                                              "or gradients of the bilinear element field.")
        self.strain_measure = ComboBox(label="Strain measure", value="green_lagrange",
                                       choices=[("Green-Lagrange", "green_lagrange"),
                                                ("infinitesimal", "infinitesimal"),
                                                ("Euler-Almansi", "euler_almansi")],
                                       tooltip="Finite-strain measure of exx, eyy, exy.")
        # ---- units
        self.pixel_size = FloatSpinBox(label="Pixel size", value=1.0, min=0.0001, max=1e6,
                                       step=0.0001,
                                       tooltip="Physical size of one image pixel; sets the "
                                               "scale of the image, its ROI layers and every "
                                               "result layer, and the unit of u, v, |u|.")
        self.unit = ComboBox(label="Length unit", value="px", choices=list(_LENGTH_UNITS),
                             tooltip="Unit of the pixel size.")
        self.frame_interval = FloatSpinBox(label="Frame interval", value=1.0, min=0.0001,
                                           max=1e9, step=0.0001,
                                           tooltip="Time between frames (time-axis scale).")
        self.time_unit = ComboBox(label="Time unit", value="frame", choices=list(_TIME_UNITS),
                                  tooltip="Unit of the frame interval.")
        # ---- display
        self.show_field = ComboBox(label="Show", value="|u|", choices=list(FIELDS),
                                   tooltip="Result image layer made visible after a run "
                                           "(the others are added hidden).")
        self.vectors = CheckBox(text="displacement vectors", value=True,
                                tooltip="Vectors layer of (u, v) at the trusted nodes; every "
                                        "node value is in its features.")
        self.vector_length = FloatSpinBox(label="Vector scale", value=0.0, min=0.0, max=1e6,
                                          step=0.5,
                                          tooltip="Arrow length per unit displacement; 0 = "
                                                  "automatic (the longest arrows span about "
                                                  "one node step).")
        self.mesh = CheckBox(text="mesh", value=False,
                             tooltip="Shapes layer of the element outlines.")
        self.deformed = CheckBox(text="deformed configuration", value=False,
                                 tooltip="Show fields, vectors, nodes and mesh where the "
                                         "material is in each frame instead of in the "
                                         "reference frame.")
        # ---- parameter files
        self.save_params_button = PushButton(
            text="Save parameters…",
            tooltip="Write the analysis settings (correlation, tracking and frame range, "
                    "strain, units) to a readable JSON file; it also works with "
                    "'napari-aldic run STACK --params FILE.json'.")
        self.load_params_button = PushButton(
            text="Load parameters…",
            tooltip="Set every parameter from a JSON file saved here or written by "
                    "'napari-aldic params' / 'run --params-out'.")
        # ---- run
        self.run_button = PushButton(text="Run")
        self.cancel_button = PushButton(text="Cancel", enabled=False)
        self.status = Label(value="")
        self.progress = ProgressBar(value=0, min=0, max=1000, label="")
        self.eta = Label(value="", label="")
        self.log = TextEdit(value="", label="")
        self.log.read_only = True

        def section(title: str) -> Label:
            return Label(value=f"<b>{title}</b>", label="")

        display = Container(widgets=[self.vectors, self.mesh, self.deformed],
                            layout="vertical", labels=False)
        # napari docks ``self.native``: the form scrolls, the run controls stay below it
        self._body = Container(scrollable=True, labels=True)
        self._body.extend([
            section("Input"), self.image, self.roi_add, self.roi_subtract, self.roi_labels,
            self.brush, self.seeds,
            section("Correlation"), self.method, self.subset, self.step, self.search,
            self.refine, self.smooth, self.smooth_px, self.init, self.reference, self.start,
            self.stop, self.stride,
            section("Strain"), self.strain_window, self.strain_method, self.strain_measure,
            section("Units"), self.pixel_size, self.unit, self.frame_interval, self.time_unit,
            section("Display"), self.show_field, display, self.vector_length,
        ])
        buttons = Container(widgets=[self.run_button, self.cancel_button], layout="horizontal",
                            labels=False)
        files = Container(widgets=[self.save_params_button, self.load_params_button],
                          layout="horizontal", labels=False)
        self._footer = Container(widgets=[self.status, files, buttons, self.progress,
                                          self.eta, self.log], labels=False)
        for sel in (self.roi_add, self.roi_subtract):
            sel.native.setMaximumHeight(64)
        from qtpy.QtWidgets import QComboBox

        for combo in (self.image, self.roi_labels, self.brush, self.seeds):
            # long layer names must not widen the dock beyond the window
            combo.native.setSizeAdjustPolicy(
                QComboBox.SizeAdjustPolicy.AdjustToMinimumContentsLengthWithIcon)
            combo.native.setMinimumContentsLength(12)
        self.status.native.setWordWrap(True)
        self.eta.native.setWordWrap(True)
        self.log.native.setMinimumHeight(90)
        self.log.native.setMaximumHeight(170)
        scroll = self._body.root_native_widget
        scroll.setFrameShape(scroll.Shape.NoFrame)
        self.native.layout().addWidget(scroll, 1)
        self.native.layout().addWidget(self._footer.native, 0)
        self.native.layout().setContentsMargins(0, 0, 0, 0)

        # ---- connections
        layers = self._viewer.layers
        layers.events.inserted.connect(self._on_inserted)
        layers.events.removed.connect(self._on_layers_changed)
        layers.events.moved.connect(self._on_layers_changed)
        for lay in list(layers):
            self._watch(lay)
        self.image.changed.connect(self._on_image_changed)
        for w in (self.roi_add, self.roi_subtract, self.roi_labels, self.brush, self.seeds,
                  self.method, self.subset, self.step, self.search, self.refine, self.init,
                  self.smooth, self.smooth_px, self.reference, self.start, self.stop,
                  self.stride, self.strain_window):
            w.changed.connect(self._validate)
        for w in (self.pixel_size, self.unit, self.frame_interval, self.time_unit):
            w.changed.connect(self._on_units_changed)
        for w in (self.mesh, self.deformed, self.vectors):
            w.changed.connect(self._refresh_results)
        self.vector_length.changed.connect(self._on_vector_length)
        self.smooth.changed.connect(self._on_smooth_mode)
        self.method.changed.connect(self._on_smooth_mode)
        # closing the widget stops a run after its frame and unhooks it from the viewer
        self.native.destroyed.connect(lambda *_: self._close())
        self.run_button.changed.connect(self.run)
        self.cancel_button.changed.connect(self.cancel)
        self.save_params_button.changed.connect(self._on_save_clicked)
        self.load_params_button.changed.connect(self._on_load_clicked)
        for lay in list(layers):
            self._auto_assign(lay)
        self._on_image_changed()

    # ------------------------------------------------------------ layer list
    def _close(self) -> None:
        self._cancel.set()
        layers = self._viewer.layers
        for emitter, slot in ((layers.events.inserted, self._on_inserted),
                              (layers.events.removed, self._on_layers_changed),
                              (layers.events.moved, self._on_layers_changed)):
            emitter.disconnect(slot)
        for lay in list(layers):
            lay.events.name.disconnect(self._on_layers_changed)
            if hasattr(lay.events, "data"):
                lay.events.data.disconnect(self._validate)

    def _watch(self, layer) -> None:
        layer.events.name.connect(self._on_layers_changed)
        if layer.__class__.__name__ in ("Shapes", "Labels", "Points"):
            layer.events.data.connect(self._validate)

    def _on_inserted(self, event=None) -> None:
        layer = getattr(event, "value", None)
        if layer is not None:
            self._watch(layer)
            if _is_result_layer(layer):
                return  # never an input: nothing to update
        self._body.reset_choices()
        if layer is not None:
            self._auto_assign(layer)
        if self.image.value is None:
            self._on_image_changed()
        self._validate()

    def _on_layers_changed(self, event=None) -> None:
        layer = getattr(event, "value", None)
        if layer is not None and _is_result_layer(layer) and getattr(event, "type", "") == \
                "removed":
            return
        self._body.reset_choices()
        self._validate()

    def _auto_assign(self, layer) -> None:
        """Preselect inputs by layer name: Shapes named 'hole'/'crack'/... -> subtract,
        other Shapes -> ROI; Labels 'roi' -> ROI labels, 'refine'/'brush' -> refinement
        region; Points 'seed' -> seeds."""
        kind = layer.__class__.__name__
        name = layer.name.lower()
        if kind == "Shapes":
            # holes by name; every other Shapes layer (e.g. a new "Shapes") adds to the ROI
            target = (self.roi_subtract if any(w in name for w in _SUBTRACT_WORDS)
                      else self.roi_add)
            if layer not in target.value:
                target.value = [*target.value, layer]
        elif kind == "Labels":
            if ("refine" in name or "brush" in name) and self.brush.value is None:
                self.brush.value = layer
            elif "roi" in name and self.roi_labels.value is None:
                self.roi_labels.value = layer
        elif kind == "Points" and "seed" in name and self.seeds.value is None:
            self.seeds.value = layer
            self.init.value = "seeds"

    # ------------------------------------------------------------ image, units
    def _stack_shape(self):
        img = self.image.value
        if img is None:
            return None
        data = img.data[0] if img.multiscale else img.data
        return tuple(data.shape)

    def _on_image_changed(self, *_) -> None:
        img = self.image.value
        if img is None:
            candidates = [c for c in self.image.choices if c is not None]
            if candidates:
                self.image.value = candidates[0]
                return
        shape = self._stack_shape()
        if shape is not None and len(shape) == 3:
            n = shape[0]
            self.start.max = max(0, n - 2)
            self.stop.max = n - 1
            self.stop.value = n - 1
            self.start.value = min(self.start.value, max(0, n - 2))
        if img is not None and img.ndim >= 2:
            self._syncing = True
            try:
                self.pixel_size.value = float(img.scale[-1])
                unit = str(img.units[-1])
                inv = {v: k for k, v in _LENGTH_UNITS.items()}
                names = {"pixel": "px", "micrometer": "µm", "nanometer": "nm",
                         "millimeter": "mm", "centimeter": "cm", "meter": "m"}
                self.unit.value = inv.get(unit, names.get(unit, "px"))
                if img.ndim == 3:
                    self.frame_interval.value = float(img.scale[0])
                    t_unit = str(img.units[0])
                    t_names = {"pixel": "frame", "second": "s", "millisecond": "ms",
                               "minute": "min", "hour": "h"}
                    self.time_unit.value = t_names.get(t_unit, "frame")
            finally:
                self._syncing = False
            self._units_applied = (self.pixel_size.value, self.frame_interval.value)
        self._validate()

    def _input_layers(self) -> list:
        out = [self.image.value, *self.roi_add.value, *self.roi_subtract.value,
               self.roi_labels.value, self.brush.value, self.seeds.value]
        seen, uniq = set(), []
        for lay in out:
            if lay is not None and id(lay) not in seen:
                seen.add(id(lay))
                uniq.append(lay)
        return uniq

    def _on_units_changed(self, *_) -> None:
        """Apply pixel size/interval and units to the image, its input layers and the
        result layers (values of u, v, |u| are shown in the length unit)."""
        if self._syncing or self.image.value is None:
            return
        p, dt = float(self.pixel_size.value), float(self.frame_interval.value)
        old_p, old_dt = self._units_applied or (1.0, 1.0)
        unit = _LENGTH_UNITS[self.unit.value]
        t_unit = _TIME_UNITS[self.time_unit.value]
        for lay in self._input_layers():
            scale = np.array(lay.scale, float)
            translate = np.array(lay.translate, float)
            scale[-2:] = scale[-2:] * (p / old_p)
            translate[-2:] = translate[-2:] * (p / old_p)
            if lay.ndim >= 3:
                scale[-3] = scale[-3] * (dt / old_dt)
                translate[-3] = translate[-3] * (dt / old_dt)
            units = [str(u) for u in lay.units]
            units[-2:] = [unit, unit]
            if lay.ndim >= 3:
                units[-3] = t_unit
            lay.scale = scale
            lay.translate = translate
            try:
                lay.units = units
            except Exception:  # unknown unit for pint: keep the scale only
                pass
        for lay in list(self._viewer.layers):  # results are rebuilt below; align units now
            if _is_result_layer(lay):
                units = [str(u) for u in lay.units]
                units[-2:] = [unit, unit]
                if lay.ndim >= 3:
                    units[-3] = t_unit
                try:
                    lay.units = units
                except Exception:
                    pass
        self._units_applied = (p, dt)
        self._log(f"units: pixel size {p:g} {self.unit.value}, frame interval {dt:g} "
                  f"{self.time_unit.value}")
        self._refresh_results()

    # ------------------------------------------------------------ validation
    def _problems(self) -> tuple[list[str], list[str]]:
        """(errors, warnings) of the current choices, in words."""
        errors, warnings_ = [], []
        img = self.image.value
        if img is None:
            return ["Choose an image stack (open a TIFF stack or a folder of images)."], []
        if img.rgb:
            errors.append(f"'{img.name}' is RGB; DIC needs grey images (open the stack with "
                          "this plugin's reader, which converts RGB to grey).")
            return errors, warnings_
        shape = self._stack_shape()
        if len(shape) != 3 or shape[0] < 2:
            errors.append(f"'{img.name}' has shape {shape}; DIC needs a stack (frames, rows, "
                          "cols) with at least two frames. Stack reference and deformed "
                          "images into one layer (File > Open with the napari-aldic reader, "
                          "or Layers > Stack).")
            return errors, warnings_
        n, rows, cols = shape
        if self.subset.value % 2 == 0:
            errors.append(f"Subset {self.subset.value} px must be odd (e.g. "
                          f"{self.subset.value + 1}).")
        if self.strain_window.value % 2 == 0:
            errors.append(f"Strain window {self.strain_window.value} must be odd.")
        if not self.start.value < self.stop.value:
            errors.append(f"First frame ({self.start.value}) must come before the last frame "
                          f"({self.stop.value}).")
        elif (self.stop.value - self.start.value) < self.stride.value:
            errors.append(f"Frames {self.start.value}..{self.stop.value} every "
                          f"{self.stride.value} hold only the reference frame.")
        try:
            roi, _ = self._roi((rows, cols))
        except Exception as exc:  # a layer that cannot be read as a region
            errors.append(f"ROI: {exc}")
            roi = None
        else:
            if roi is not None:
                if not roi.any():
                    errors.append("The ROI is empty: draw shapes on the material or choose "
                                  "other ROI layers.")
                else:
                    ys, xs = np.nonzero(roi)
                    bh, bw = ys.max() - ys.min() + 1, xs.max() - xs.min() + 1
                    if self.subset.value > min(bh, bw):
                        errors.append(f"Subset {self.subset.value} px is larger than the ROI "
                                      f"bounding box ({bw} x {bh} px); reduce the subset or "
                                      "enlarge the ROI.")
        if self.subset.value + 2 > min(rows, cols):
            errors.append(f"Subset {self.subset.value} px does not fit in the image "
                          f"({cols} x {rows} px).")
        if self.init.value == "seeds":
            pts = self.seeds.value
            if pts is None or len(pts.data) == 0:
                errors.append("Initial guess 'seed points' needs a Points layer with at least "
                              "one point (choose it under 'Seeds').")
            else:
                xy = points_xy(pts, img)
                inside = [(0 <= x < cols and 0 <= y < rows
                           and (roi is None or roi[int(round(y)), int(round(x))]))
                          for x, y in xy]
                if not all(inside):
                    bad = [f"({x:.0f}, {y:.0f})" for (x, y), ok in zip(xy, inside) if not ok]
                    errors.append(f"Seed point(s) {', '.join(bad)} (x, y) lie outside the ROI; "
                                  "move them onto analysed material.")
        if self.brush.value is not None:
            try:
                labels_mask(self.brush.value, (rows, cols), self.start.value)
            except ValueError as exc:
                errors.append(f"Refine region: {exc}")
            if self.reference.value != "accumulative":
                errors.append("A painted refine region needs 'accumulative' tracking.")
        if self.step.value > self.subset.value:
            warnings_.append(f"Step {self.step.value} px is larger than the subset: pixels "
                             "between subsets are not used.")
        return errors, warnings_

    def _validate(self, *_) -> bool:
        try:
            errors, warns = self._problems()
        except Exception as exc:  # never let a check break the widget
            errors, warns = [f"Cannot check the inputs: {exc}"], []
        lines = [f"<span style='color:#ff6b6b'>&#9888; {e}</span>" for e in errors]
        lines += [f"<span style='color:#f0c040'>{w}</span>" for w in warns]
        if not errors:
            lines.insert(0, "<span style='color:#6bd66b'>Ready.</span>")
        self.status.value = "<br>".join(lines)
        self.run_button.enabled = not errors and not self.running
        self._errors = errors
        return not errors

    # ------------------------------------------------------------ inputs -> arrays
    def _roi(self, image_shape):
        img = self.image.value
        return build_roi(img, image_shape, add_shapes=list(self.roi_add.value),
                         subtract_shapes=list(self.roi_subtract.value),
                         labels=self.roi_labels.value, frame=self.start.value)

    def _job(self) -> _Job:
        img = self.image.value
        data = img.data[0] if img.multiscale else img.data
        n, rows, cols = data.shape
        roi, notes = self._roi((rows, cols))
        params = self._current_params()
        seeds, refine = params.seeds, params.refine
        brush = None
        if self.brush.value is not None:
            brush = labels_mask(self.brush.value, (rows, cols), self.start.value)
            if not brush.any():
                brush = None
        strain = StrainSettings(window=int(self.strain_window.value),
                                method=self.strain_method.value,
                                measure=self.strain_measure.value)
        stop = int(self.stop.value)
        n_roi = rows * cols if roi is None else int(roi.sum())
        summary = (f"image '{img.name}' ({n} frames, {cols} x {rows} px, {data.dtype}); "
                   f"frames {self.start.value}..{stop} every {self.stride.value}, "
                   f"{self.reference.value}; ROI {n_roi} px"
                   + (f" [{'; '.join(notes)}]" if notes else " (whole image)")
                   + f"; method {params.method}, subset {params.subset} px, step "
                   f"{params.step} px, search {params.search} px, init {params.init}"
                   + (f" ({len(seeds)} seeds)" if seeds else "")
                   + f", refinement {refine or 'none'}"
                   + (f" + brush region ({int(brush.sum())} px)" if brush is not None else "")
                   + (f", smoothing {params.smooth}" if params.method == "aldic" else "")
                   + f"; strain {strain.method}, window {strain.window}, {strain.measure}"
                   + (f"; from the parameter file: {_describe_extra(self._extra_params)}"
                      if self._extra_params else ""))
        return _Job(stack=data, roi=roi, params=params, reference=self.reference.value,
                    start=int(self.start.value), stop=stop, stride=int(self.stride.value),
                    brush=brush, strain=strain, source=img.name, summary=summary)

    # ------------------------------------------------------------ parameter files
    def _current_params(self) -> DICParams:
        """The DICParams of the controls (seed points from the seeds layer, in image
        pixels), with the fields the widget does not show from the last loaded file."""
        seeds: tuple = ()
        if self.init.value == "seeds":
            layer = self.seeds.value
            if layer is None or len(layer.data) == 0:
                raise ValueError("the initial guess 'Seed points' needs a Points layer with at "
                                 "least one point (choose it under 'Seeds (points)')")
            img = self.image.value
            xy = (points_xy(layer, img) if img is not None
                  else np.asarray(layer.data, float)[:, -2:][:, ::-1])
            seeds = tuple((float(x), float(y)) for x, y in xy)
        extra = dict(self._extra_params)
        if extra.get("search_max") is not None and extra["search_max"] < self.search.value:
            extra["search_max"] = int(self.search.value)  # the search cannot start wider
        return DICParams.from_dict({
            **extra, "method": self.method.value, "subset": int(self.subset.value),
            "step": int(self.step.value), "search": int(self.search.value),
            "refine": None if self.refine.value == "none" else self.refine.value,
            "smooth": self._smooth_value(), "init": self.init.value, "seeds": seeds})

    def _on_smooth_mode(self, *_) -> None:
        aldic = self.method.value == "aldic"
        self.smooth.enabled = aldic
        self.smooth_px.enabled = aldic and self.smooth.value == "fixed"

    def _smooth_value(self) -> float | str:
        mode = self.smooth.value
        return "auto" if mode == "auto" else 0.0 if mode == "off" else float(self.smooth_px.value)

    def _current_units(self) -> Units:
        ps, unit = float(self.pixel_size.value), self.unit.value
        if unit == "px" and ps != 1.0:
            raise ValueError(f"the pixel size is {ps:g} with the length unit 'px': choose the "
                             "physical unit of the pixel size (e.g. µm), or set the pixel size "
                             "to 1")
        if self.time_unit.value == "frame":  # no physical time: frame numbers only
            return Units(ps, unit)
        return Units(ps, unit, float(self.frame_interval.value), self.time_unit.value)

    def current_settings(self) -> dict[str, Any]:
        """The complete analysis settings of the controls, as
        :func:`~napari_aldic.engine.export.save_params` takes them:
        ``{"params": DICParams, "units": Units, "strain": dict, "tracking": dict}``.

        Raises ``ValueError`` when the controls do not make valid settings (an
        even subset, 'Seed points' without points, a pixel size in 'px' ...).
        """
        return {
            "params": self._current_params(),
            "units": self._current_units(),
            "strain": {"window": int(self.strain_window.value),
                       "method": self.strain_method.value,
                       "measure": self.strain_measure.value},
            "tracking": {"reference": self.reference.value, "start": int(self.start.value),
                         "stop": int(self.stop.value), "stride": int(self.stride.value)},
        }

    def save_settings(self, path) -> Path | None:
        """Write the current settings to the JSON file ``path`` (``.json`` is
        appended when missing) with :func:`~napari_aldic.engine.export.save_params`.

        Returns the path written, or ``None`` after an error notification and a
        log line (nothing is written then). The file also works with
        ``napari-aldic run STACK --params FILE.json``.
        """
        from napari.utils.notifications import show_error

        from .engine import save_params

        try:
            s = self.current_settings()
            written = save_params(path, s["params"], units=s["units"], strain=s["strain"],
                                  tracking=s["tracking"])
        except Exception as exc:  # invalid settings, unwritable file: explain, never crash
            msg = _message(exc)
            self._log(f"ERROR saving the parameters to {path}: {msg}")
            show_error(f"napari-aldic: could not save the parameters: {msg}")
            return None
        self._settings_dir = written.parent
        self._log(f"parameters saved to {written}: {self._settings_summary()}")
        return written

    def load_settings(self, path) -> bool:
        """Set every control from a parameter file (see :meth:`save_settings`;
        also files of ``napari-aldic params`` / ``run --params-out``, or a plain
        JSON object of DICParams fields).

        The whole file is checked first: an unreadable file or invalid content
        gives an error notification and a log line, and leaves the widget
        unchanged (returns ``False``). Sections missing from the file (units,
        strain, tracking) leave their controls as they are. DICParams fields the
        widget does not show (e.g. ``interpolation``, ``mu``) are kept for runs
        and for saving. Seed points of the file are added as a Points layer when
        no seeds layer with points is chosen. A frame range beyond the current
        stack is clamped to it (noted in the log).
        """
        from napari.utils.notifications import show_error, show_warning

        try:
            plan, extra, seeds, notes = self._settings_plan(path)
        except Exception as exc:  # unreadable or invalid file: nothing is changed
            msg = _message(exc)
            self._log(f"ERROR loading parameters from {path}: {msg}")
            show_error(f"napari-aldic: could not load the parameters: {msg}")
            return False
        units_before = self._unit_values()
        before = [(w, w.value) for w, _ in plan]
        extra_before = self._extra_params
        try:
            self._apply_plan(plan)
            self._extra_params = extra
            if seeds:
                self._restore_seeds(seeds, notes)
        except Exception as exc:  # pragma: no cover - the plan was checked beforehand
            try:
                self._apply_plan(before)
            except Exception:
                pass
            self._extra_params = extra_before
            msg = _message(exc)
            self._log(f"ERROR loading parameters from {path}: {msg}")
            show_error(f"napari-aldic: could not load the parameters: {msg}")
            self._validate()
            return False
        if self._unit_values() != units_before:
            try:  # rescale the image and its layers once, for all unit controls
                self._on_units_changed()
            except Exception as exc:  # pragma: no cover - a layer refusing its scale
                show_error(f"napari-aldic: could not apply the units: {_message(exc)}")
                self._log(f"ERROR applying the units: {_message(exc)}")
        self._settings_dir = Path(os.fspath(path)).expanduser().parent
        self._log(f"parameters loaded from {path}: {self._settings_summary()}")
        if extra:
            self._log(f"kept from the file (not shown in the widget): "
                      f"{_describe_extra(extra)}")
        for note in notes:
            self._log(note)
        if any(n.startswith("frame range") for n in notes):
            show_warning("napari-aldic: " + next(n for n in notes
                                                 if n.startswith("frame range")))
        self._validate()
        return True

    def _settings_plan(self, path):
        """Read and check a parameter file: ``(plan, extra, seeds, notes)``, the
        plan a list of ``(control, value)``; raises ``ValueError`` on any problem."""
        from .engine.io import load_settings as read_settings

        s = read_settings(path)
        params: DICParams = s["params"]
        plan: list[tuple[Any, Any]] = []
        notes: list[str] = []

        def put(widget, value, what: str) -> None:
            _check_value(widget, value, what)
            plan.append((widget, value))

        put(self.method, params.method, "method")
        put(self.subset, params.subset, "subset")
        put(self.step, params.step, "step")
        put(self.search, params.search, "search")
        put(self.refine, params.refine or "none", "refinement")
        put(self.init, params.init, "initial guess")
        if params.smooth == "auto":
            put(self.smooth, "auto", "AL-DIC smoothing")
        elif params.smooth == 0:
            put(self.smooth, "off", "AL-DIC smoothing")
        else:
            put(self.smooth, "fixed", "AL-DIC smoothing")
            put(self.smooth_px, float(params.smooth), "smoothing length")
        defaults = DICParams().to_dict()
        extra = {k: v for k, v in params.to_dict().items()
                 if k not in _PARAM_CONTROLS and k != "seeds" and v != defaults[k]}
        seeds = params.seeds if params.init == "seeds" else ()

        strain = _section(s["strain"], "strain", _STRAIN_KEYS)
        if "window" in strain:
            window = _as_int(strain["window"], "strain window")
            if window % 2 == 0:
                raise ValueError(f"strain window {window} must be odd")
            put(self.strain_window, window, "strain window")
        if "method" in strain:
            put(self.strain_method, strain["method"], "strain method")
        if "measure" in strain:
            put(self.strain_measure, strain["measure"], "strain measure")

        tracking = _section(s["tracking"], "tracking", _TRACKING_KEYS)
        if "reference" in tracking:
            put(self.reference, tracking["reference"], "tracking")
        if "stride" in tracking:
            put(self.stride, _as_int(tracking["stride"], "frame stride"), "frame stride")
        start = stop = None
        if tracking.get("start") is not None:
            start = _as_int(tracking["start"], "first frame")
            if start < 0:
                raise ValueError(f"first frame {start} must be >= 0")
        if tracking.get("stop") is not None:
            stop = _as_int(tracking["stop"], "last frame")
            if stop < 1:
                raise ValueError(f"last frame {stop} must be >= 1")
            if start is not None and not start < stop:
                raise ValueError(f"the first frame ({start}) must come before the last "
                                 f"frame ({stop})")
        elif "stop" in tracking:  # null: the last frame of the stack
            stop = int(self.stop.max)
        shape = self._stack_shape()
        n = shape[0] if shape is not None and len(shape) == 3 else None
        stack = f"the stack has {n} frames" if n else "no image stack is chosen"
        if start is not None:
            if start > self.start.max:
                notes.append(f"frame range: first frame {start} of the file is beyond the "
                             f"stack ({stack}); using {self.start.max}")
                start = int(self.start.max)
            plan.append((self.start, start))
        if stop is not None:
            if stop > self.stop.max:
                notes.append(f"frame range: last frame {stop} of the file is beyond the "
                             f"stack ({stack}); using {self.stop.max}")
                stop = int(self.stop.max)
            plan.append((self.stop, stop))

        units: Units | None = s["units"]
        if units is not None:
            unit = _unit_name(units.unit, _LENGTH_UNITS, _LENGTH_ALIASES, "length unit")
            put(self.unit, unit, "length unit")
            put(self.pixel_size, units.pixel_size, "pixel size")
            if units.frame_interval is None:
                put(self.time_unit, "frame", "time unit")
                put(self.frame_interval, 1.0, "frame interval")
            else:
                t_unit = _unit_name(units.time_unit, _TIME_UNITS, _TIME_ALIASES, "time unit")
                put(self.time_unit, t_unit, "time unit")
                put(self.frame_interval, units.frame_interval, "frame interval")
        return plan, extra, seeds, notes

    def _apply_plan(self, plan) -> None:
        self._syncing = True  # units are applied to the layers once, afterwards
        try:
            for widget, value in plan:
                if isinstance(widget, FloatSpinBox):
                    _fit_decimals(widget, float(value))
                widget.value = value
        finally:
            self._syncing = False

    def _unit_values(self) -> tuple:
        return (self.pixel_size.value, self.unit.value, self.frame_interval.value,
                self.time_unit.value)

    def _restore_seeds(self, seeds, notes: list[str]) -> None:
        """Seed points ``(x, y)`` in image pixels as a new Points layer, unless a
        seeds layer with points is chosen already."""
        layer = self.seeds.value
        if layer is not None and len(layer.data):
            notes.append(f"the file's {len(seeds)} seed point(s) were not added: the seeds "
                         f"layer '{layer.name}' is used")
            return
        img = self.image.value
        rc = np.array([(y, x) for x, y in seeds], float)
        kwargs: dict[str, Any] = {}
        if img is not None:  # the image's pixel grid (its current scale and offset)
            kwargs = {"scale": tuple(img.scale)[-2:], "translate": tuple(img.translate)[-2:]}
        new = self._viewer.add_points(rc, name="seeds (loaded)", size=6, face_color="cyan",
                                      **kwargs)
        if img is not None:
            try:
                new.units = [str(u) for u in img.units][-2:]
            except Exception:  # units are cosmetic here; the scale is what counts
                pass
        self.seeds.value = new
        notes.append(f"{len(seeds)} seed point(s) from the file added as the Points layer "
                     f"'{new.name}'")

    def _settings_summary(self) -> str:
        refine = self.refine.value
        t = ("frame numbers" if self.time_unit.value == "frame"
             else f"frame interval {self.frame_interval.value:g} {self.time_unit.value}")
        return (f"method {self.method.value}, subset {self.subset.value} px, step "
                f"{self.step.value} px, search {self.search.value} px, refinement {refine}, "
                f"smoothing {self._smooth_value()}, "
                f"init {self.init.value}; {self.reference.value}, frames "
                f"{self.start.value}..{self.stop.value} every {self.stride.value}; strain "
                f"{self.strain_method.value}, window {self.strain_window.value}, "
                f"{self.strain_measure.value}; pixel size {self.pixel_size.value:g} "
                f"{self.unit.value}, {t}")

    def _settings_start(self, name: str = "") -> str:
        """Where the file dialogs open: the last parameter file's folder, else the
        image's folder, else the working folder."""
        folder = self._settings_dir
        if folder is None:
            img = self.image.value
            src = getattr(getattr(img, "source", None), "path", None) if img is not None else None
            folder = Path(src).parent if src else Path.cwd()
        return str(folder / name) if name else str(folder)

    def _on_save_clicked(self, *_) -> None:
        from qtpy.QtWidgets import QFileDialog

        img = self.image.value
        stem = "".join(c if c.isalnum() or c in "-_." else "_" for c in img.name) \
            if img is not None else "dic"
        path, _ = QFileDialog.getSaveFileName(self.native, "Save DIC parameters",
                                              self._settings_start(f"{stem}_parameters.json"),
                                              _JSON_FILTER)
        if path:
            self.save_settings(path)

    def _on_load_clicked(self, *_) -> None:
        from qtpy.QtWidgets import QFileDialog

        path, _ = QFileDialog.getOpenFileName(self.native, "Load DIC parameters",
                                              self._settings_start(), _JSON_FILTER)
        if path:
            self.load_settings(path)

    # ------------------------------------------------------------ running
    def run(self, *_) -> None:
        """Start the analysis in a worker thread (no-op while one runs)."""
        from napari.qt.threading import create_worker
        from napari.utils.notifications import show_error, show_warning

        if self.running:
            return
        if not self._validate():
            show_warning("napari-aldic: " + " ".join(self._errors))
            return
        try:
            job = self._job()
        except Exception as exc:
            show_error(f"napari-aldic: could not prepare the run: {exc}")
            self._log(f"ERROR preparing the run: {exc}")
            return
        self._cancel.clear()
        self._analysis_image = self.image.value
        self._n_deformed = len(range(job.start, job.stop + 1, job.stride)) - 1
        self._log(f"Run {time.strftime('%H:%M:%S')}: {job.summary}")
        # superqt's plain worker: errors reach _on_errored only (one notification)
        from superqt.utils import GeneratorWorker

        worker = create_worker(_work, job, self._cancel, _worker_class=GeneratorWorker,
                               _ignore_errors=True)
        worker.yielded.connect(self._on_progress)
        worker.returned.connect(self._on_returned)
        worker.errored.connect(self._on_errored)
        worker.finished.connect(self._on_finished)
        self._worker = worker
        self._set_running(True)
        self._t0 = time.perf_counter()
        self.progress.value = 0
        self.eta.value = f"0/{self._n_deformed} frames"
        worker.start()

    def cancel(self, *_) -> None:
        """Stop after the frame being computed; finished frames are kept."""
        if self.running:
            self._cancel.set()
            self.cancel_button.enabled = False
            self.eta.value = "cancelling after the current frame ..."
            self._log("Cancel requested: stopping after the current frame.")

    def _set_running(self, running: bool) -> None:
        self.running = running
        self.cancel_button.enabled = running
        self.load_params_button.enabled = not running  # a run keeps the settings it started with
        self._validate()

    def _on_progress(self, item) -> None:
        frame, frac, msg = item
        frac = float(min(max(frac, 0.0), 1.0))
        self.progress.value = int(round(1000 * frac))
        done = int(round(frac * self._n_deformed))
        elapsed = time.perf_counter() - self._t0
        left = f" · about {_fmt_seconds(elapsed * (1 - frac) / frac)} left" if 0 < frac < 1 else ""
        if not self._cancel.is_set():
            self.eta.value = (f"{done}/{self._n_deformed} frames · "
                              f"{_fmt_seconds(elapsed)} elapsed{left}")
        if "done" in msg or "strain" in msg:
            self._log(msg)

    def _on_returned(self, analysis: Analysis) -> None:
        from napari.utils.notifications import show_error, show_info

        self._analysis = analysis
        done = analysis.n_done - 1
        state = "cancelled" if analysis.cancelled else "finished"
        self._log(f"{state} in {analysis.seconds:.1f} s: {done}/{len(analysis.frames) - 1} "
                  "frames computed")
        last = next((r for r in reversed(analysis.results) if r is not None), None)
        if last is not None and done > 0:
            self._log(last.summary())
        try:
            self._show_results()
            self._go_to_last_frame()
        except Exception as exc:  # never crash the viewer on a display problem
            show_error(f"napari-aldic: could not show the results: {exc}")
            self._log(f"ERROR showing results: {exc}")
            return
        self.eta.value = (f"{done}/{len(analysis.frames) - 1} frames · {state} in "
                          f"{_fmt_seconds(analysis.seconds)}")
        if analysis.cancelled:
            show_info(f"napari-aldic: cancelled; {done} finished frame(s) kept")

    def _on_errored(self, exc: BaseException) -> None:
        from napari.utils.notifications import show_error

        msg = str(exc) or exc.__class__.__name__
        self._log(f"ERROR: {msg}")
        self.eta.value = "failed (see log)"
        show_error(f"napari-aldic: {msg}")

    def _on_finished(self) -> None:
        self._worker = None
        self._set_running(False)

    # ------------------------------------------------------------ results -> layers
    def _geometry(self) -> Geometry:
        img = self._analysis_image if self._analysis_image is not None else self.image.value
        return Geometry(scale=tuple(img.scale), translate=tuple(img.translate),
                        units=tuple(str(u) for u in img.units),
                        axis_labels=tuple(img.axis_labels))

    def _display(self) -> Display:
        return Display(visible_field=self.show_field.value, vectors=self.vectors.value,
                       vector_length=float(self.vector_length.value), mesh=self.mesh.value,
                       deformed=self.deformed.value,
                       length_scale=float(self.pixel_size.value),
                       length_unit=self.unit.value,
                       frame_interval=(None if self.time_unit.value == "frame"
                                       else float(self.frame_interval.value)),
                       time_unit=self.time_unit.value)

    def _show_results(self) -> None:
        if self._analysis is None:
            return
        if self._analysis_image is not None and self._analysis_image not in self._viewer.layers:
            self._analysis_image = None
        if self._analysis_image is None and self.image.value is None:
            return
        tuples = analysis_layers(self._analysis, self._geometry(), self._display())
        made = {kw["name"] for _, kw, _ in tuples}
        layers = self._viewer.layers
        # layers this display no longer makes (e.g. mesh switched off) go away
        for key in ("displacement", "unreliable nodes", "mesh"):
            name = layer_name(key)
            if name not in made and name in layers:
                layers.remove(name)
        for data, kw, kind in tuples:
            name = kw["name"]
            if name in layers:
                old = layers[name]
                if _update_layer(old, data, kw, kind):
                    continue
                # a different kind or number of axes: replace it at the same place
                kw["visible"] = old.visible
                index = layers.index(old)
                layers.remove(old)
                new = getattr(self._viewer, f"add_{kind}")(data, **kw)
                layers.move(layers.index(new), index)
            else:
                getattr(self._viewer, f"add_{kind}")(data, **kw)
        vis = layer_name(self.show_field.value)
        if vis in layers and hasattr(layers[vis], "colorbar"):
            layers[vis].colorbar.visible = True

    def _go_to_last_frame(self) -> None:
        """Show the last computed frame (frame 0, the reference, is a zero field)."""
        a, img = self._analysis, self._analysis_image
        if a is None or img is None or a.n_frames is None or img not in self._viewer.layers:
            return
        done = [k for k, r in zip(a.frames, a.results) if r is not None]
        if len(done) < 2:
            return
        axis = self._viewer.dims.ndim - img.ndim  # the image's time axis in world dims
        world = float(img.translate[0]) + done[-1] * float(img.scale[0])
        self._viewer.dims.set_point(axis, world)

    def _refresh_results(self, *_) -> None:
        if self._analysis is None or self.running:
            return
        try:
            self._show_results()
        except Exception as exc:
            from napari.utils.notifications import show_error

            show_error(f"napari-aldic: could not update the results: {exc}")

    def _on_vector_length(self, *_) -> None:
        name = layer_name("displacement")
        if self.vector_length.value <= 0:
            self._refresh_results()  # automatic length: computed from the field
        elif name in self._viewer.layers:
            self._viewer.layers[name].length = float(self.vector_length.value)

    # ------------------------------------------------------------ log
    def _log(self, text: str) -> None:
        stamp = time.strftime("%H:%M:%S")
        self.log.value = (self.log.value + "\n" if self.log.value else "") + f"[{stamp}] {text}"
        bar = self.log.native.verticalScrollBar()
        bar.setValue(bar.maximum())


_JSON_FILTER = "DIC parameters (*.json);;All files (*)"


def _message(exc: BaseException) -> str:
    """One line describing an error."""
    msg = str(exc) or exc.__class__.__name__
    if isinstance(exc, FileNotFoundError) and not str(exc).strip():
        msg = f"no such file: {exc.filename}"
    return " ".join(line.strip() for line in msg.splitlines() if line.strip())


def _describe_extra(extra: dict) -> str:
    return ", ".join(f"{k}={v!r}" for k, v in extra.items())


def _section(value, name: str, keys: tuple[str, ...]) -> dict:
    """A settings section as a dict (``{}`` when absent), unknown keys rejected."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ValueError(f"the '{name}' section must be a JSON object with "
                         f"{', '.join(keys)}")
    unknown = sorted(set(value) - set(keys))
    if unknown:
        raise ValueError(f"unknown {name} setting(s) {unknown}; valid names are {list(keys)}")
    return value


def _as_int(value, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            (isinstance(value, float) and not value.is_integer()):
        raise ValueError(f"{what} {value!r} must be a whole number")
    return int(value)


def _unit_name(name, known: dict, aliases: dict, what: str) -> str:
    """The widget's spelling of a unit name from a file."""
    if isinstance(name, str):
        if name in known:
            return name
        alias = aliases.get(name.strip().lower(), aliases.get(name.strip()))
        if alias is not None:
            return alias
    raise ValueError(f"{what} {name!r} is not one the widget offers ({', '.join(known)})")


def _check_value(widget, value, what: str) -> None:
    """Raise ``ValueError`` unless ``widget`` can take ``value`` as it is."""
    if isinstance(widget, ComboBox):
        if value not in widget.choices:
            raise ValueError(f"{what} {value!r} is not one of {list(widget.choices)}")
        return
    if isinstance(widget, FloatSpinBox):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                not math.isfinite(value):
            raise ValueError(f"{what} {value!r} must be a number")
    elif isinstance(widget, SpinBox):
        value = _as_int(value, what)
    if not widget.min <= value <= widget.max:
        raise ValueError(f"{what} {value:g} is outside the range {widget.min:g}..{widget.max:g} "
                         "of the widget")


def _fit_decimals(spin: FloatSpinBox, value: float) -> None:
    """Show enough decimals in ``spin`` to hold ``value`` exactly (up to 10)."""
    native = spin.native
    if not hasattr(native, "decimals"):  # pragma: no cover - another backend
        return
    d = native.decimals()
    while d < 10 and abs(round(value, d) - value) > 1e-12 * max(1.0, abs(value)):
        d += 1
    if d > native.decimals():
        native.setDecimals(d)


def _update_layer(layer, data, kw: dict, kind: str) -> bool:
    """Update a result layer in place (cheaper than removing and adding it, and
    the user's visibility and opacity stay). False if it must be replaced."""
    ndim = len(kw["scale"])
    if layer.__class__.__name__.lower() != kind or layer.ndim != ndim or kind == "shapes":
        return False
    common = ("scale", "translate", "units", "axis_labels")
    if kind == "image":
        layer.data = data
        for key in common:
            if key in kw:
                setattr(layer, key, kw[key])
        layer.colormap = kw["colormap"]
        layer.contrast_limits_range = kw["contrast_limits"]
        layer.contrast_limits = kw["contrast_limits"]
    elif kind == "vectors":
        layer.data = data
        for key in common:
            if key in kw:
                setattr(layer, key, kw[key])
        layer.features = kw["features"]
        layer.length = kw["length"]
        layer.edge_width = kw["edge_width"]
        if kw.get("edge_color") == "magnitude":
            layer.edge_colormap = kw["edge_colormap"]
            layer.edge_color = "magnitude"
    elif kind == "points":
        layer.data = data
        for key in common:
            if key in kw:
                setattr(layer, key, kw[key])
        layer.features = kw["features"]
        if len(data):
            layer.face_color = kw["face_color"]
            layer.size = kw["size"]
    else:
        return False
    layer.metadata = kw["metadata"]
    return True


def _work(job: _Job, cancel: threading.Event):
    """Worker body: run the analysis in a helper thread and yield its progress.

    ``run_analysis`` reports through a callback; the callback queues the
    reports and this generator yields them, so napari delivers each one to
    the main thread (``yielded`` signal). The return value (an
    :class:`Analysis`) arrives through ``returned``; an exception through
    ``errored``.
    """
    reports: queue.Queue = queue.Queue()
    box: dict = {}

    def target():
        try:
            box["result"] = run_analysis(
                job.stack, job.roi, job.params, reference=job.reference, start=job.start,
                stop=job.stop, stride=job.stride, brush=job.brush, strain=job.strain,
                progress=lambda k, frac, msg: reports.put((k, frac, msg)),
                cancel=cancel.is_set, source=job.source)
        except BaseException as exc:  # handed to the worker's errored signal
            box["error"] = exc
        finally:
            reports.put(None)

    thread = threading.Thread(target=target, name="napari-aldic-analysis", daemon=True)
    thread.start()
    while True:
        item = reports.get()
        if item is None:
            break
        yield item
    thread.join()
    if "error" in box:
        raise box["error"]
    return box["result"]
