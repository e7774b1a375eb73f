"""The Mesh & correlation panel: DIC parameters, tracking and the frame range.

It makes the run's :class:`~napari_aldic.engine.DICParams`; parameters the
panel does not show (e.g. ``interpolation``, ``mu``) are kept from the last
loaded settings file in :attr:`CorrelationPanel.extra_params`.
"""

from __future__ import annotations

from typing import Any

from magicgui.widgets import ComboBox, FloatSpinBox, PushButton, SpinBox
from psygnal import Signal

from ..engine import DICParams
from ..i18n import tr
from .controls import Panel, Plan, put
from .model import DEFAULT_PARAMS, PARAM_CONTROLS

__all__ = ["CorrelationPanel", "PARAM_CONTROLS"]

#: the controls' starting values (the model's: the engine's defaults but the method)
DEFAULTS = DEFAULT_PARAMS



class CorrelationPanel(Panel):
    """Correlation method, subset, step, search, refinement, smoothing, initial
    guess, tracking strategy and frame range.

    Signals
    -------
    settings_changed
        A parameter that the input check depends on changed.
    """

    settings_changed = Signal()
    #: the "Advise subset" button was clicked (the widget runs the advice)
    advise_requested = Signal()

    def __init__(self):
        self._extra_params: dict[str, Any] = {}
        super().__init__()

    def _setup_ui(self) -> None:
        self.method = ComboBox(label=tr("Method"), value=DEFAULTS.method,
                               choices=[(tr("AL-DIC"), "aldic"), (tr("Local (IC-GN)"), "local")],
                               tooltip=tr("AL-DIC couples the subsets to a compatible finite-"
                                       "element field (smoother, robust); Local solves every "
                                       "subset on its own (faster)."))
        self.subset = SpinBox(label=tr("Subset (px)"), value=DEFAULTS.subset, min=7, max=2001,
                              step=2,
                              tooltip=tr("Odd full width of the square correlation subset in "
                                      "pixels (31 = 31 x 31). Larger: less noise, less "
                                      "spatial resolution. It should hold ~3 speckles across."))
        self.step = SpinBox(label=tr("Step (px)"), value=DEFAULTS.step, min=1, max=1000,
                            tooltip=tr("Node spacing in pixels."))
        self.target_noise = FloatSpinBox(
            label=tr("Target noise (px)"), value=0.01, min=0.0005, max=1.0, step=0.001,
            tooltip=tr("Displacement noise (standard deviation, px) the subset advice aims "
                       "for."))
        self.advise = PushButton(
            text=tr("Advise subset"),
            tooltip=tr("Predict the displacement noise of each subset size from the "
                       "reference frame's speckle and noise, and log the smallest subset "
                       "that meets the target noise."))
        self.search = SpinBox(label=tr("Search (px)"), value=DEFAULTS.search, min=1, max=100000,
                              tooltip=tr("Initial half-range of the FFT cross-correlation "
                                      "search; it widens by itself when the peak lies on "
                                      "its border."))
        self.refine = ComboBox(label=tr("Refinement"), value="none",
                               choices=[(tr("none"), "none"), (tr("light"), "light"),
                                        (tr("medium"), "medium"), (tr("strong"), "strong")],
                               tooltip=tr("Adaptive quadtree preset: light = near holes/cracks; "
                                       "medium = also the ROI outline; strong = also where "
                                       "the correlation is poor (slower)."))
        self.smooth = ComboBox(label=tr("AL-DIC smoothing"), value="auto",
                               choices=[(tr("auto (from the noise)"), "auto"),
                                        (tr("off (plain Algorithm 1)"), "off"),
                                        (tr("fixed length"), "fixed")],
                               tooltip=tr("Curvature regulariser of the AL-DIC global step "
                                       "(never biases uniform strain). auto: the length "
                                       "that minimises the estimated error for these "
                                       "images (~0 for clean images); off: none; fixed: "
                                       "the length below."))
        self.smooth_px = FloatSpinBox(label=tr("Smoothing length (px)"), value=10.0, min=0.5,
                                      max=10000.0, step=0.5, enabled=False,
                                      tooltip=tr("Displacement waves shorter than ~2 pi x this "
                                              "length are damped (fixed smoothing only)."))
        self.shape_function = ComboBox(
            label=tr("Subset shape"), value=DEFAULTS.shape_function,
            choices=[(tr("affine"), "affine"), (tr("quadratic"), "quadratic")],
            tooltip=tr("affine: subsets stretch, shear and rotate. quadratic: they may also "
                       "bend, which keeps displacement detail finer than a subset (more "
                       "noise, slower). With AL-DIC it shapes the first local step."))
        self.init = ComboBox(label=tr("Initial guess"), value=DEFAULTS.init,
                             choices=[(tr("FFT cross-correlation"), "fft"),
                                      (tr("Seed points"), "seeds")],
                             tooltip=tr("FFT: automatic search. Seed points: propagate from the "
                                     "points of the seeds layer (large or uneven motion)."))
        self._setup_tracking_ui()
        self.extend([self.method, self.subset, self.step, self.target_noise, self.advise,
                     self.search, self.refine, self.shape_function,
                     self.smooth, self.smooth_px, self.init, self.reference,
                     self.start, self.stop, self.stride])

    def _setup_tracking_ui(self) -> None:
        self.reference = ComboBox(label=tr("Tracking"), value="accumulative",
                                  choices=[(tr("accumulative"), "accumulative"),
                                           (tr("incremental"), "incremental")],
                                  tooltip=tr("accumulative: every frame against the first; "
                                          "incremental: each frame against the previous one, "
                                          "composed back to the first (large deformation)."))
        self.start = SpinBox(label=tr("First frame"), value=0, min=0, max=0,
                             tooltip=tr("Reference frame: the first frame analysed."))
        self.stop = SpinBox(label=tr("Last frame"), value=0, min=0, max=0,
                            tooltip=tr("Last frame analysed (inclusive)."))
        self.stride = SpinBox(label=tr("Every n-th frame"), value=1, min=1, max=100000,
                              tooltip=tr("Analyse every n-th frame of the range."))

    def _setup_callbacks(self) -> None:
        for w in (self.method, self.subset, self.step, self.search, self.refine,
                  self.shape_function, self.init,
                  self.smooth, self.smooth_px, self.reference, self.start, self.stop,
                  self.stride):
            w.changed.connect(self.settings_changed.emit)
        self.smooth.changed.connect(self._on_smooth_mode)
        self.advise.changed.connect(lambda *_: self.advise_requested.emit())
        self.method.changed.connect(self._on_smooth_mode)

    def _on_smooth_mode(self, *_) -> None:
        aldic = self.method.value == "aldic"
        self.smooth.enabled = aldic
        self.smooth_px.enabled = aldic and self.smooth.value == "fixed"

    # ------------------------------------------------------------ state
    @property
    def extra_params(self) -> dict[str, Any]:
        """DICParams fields not shown in the panel, kept from a loaded file."""
        return dict(self._extra_params)

    @extra_params.setter
    def extra_params(self, value: dict[str, Any]) -> None:
        self._extra_params = dict(value)

    @property
    def smooth_value(self) -> float | str:
        """The ``smooth`` parameter of the controls: "auto", 0.0 (off) or a length."""
        mode = self.smooth.value
        return "auto" if mode == "auto" else 0.0 if mode == "off" else float(self.smooth_px.value)

    @property
    def tracking(self) -> dict[str, Any]:
        """The tracking strategy and frame range, as a settings file holds them."""
        return {"reference": self.reference.value, "start": int(self.start.value),
                "stop": int(self.stop.value), "stride": int(self.stride.value)}

    def set_frame_count(self, n: int) -> None:
        """Limit the frame range to a stack of ``n`` frames (the last frame chosen)."""
        self.start.max = max(0, n - 2)
        self.stop.max = n - 1
        self.stop.value = n - 1
        self.start.value = min(self.start.value, max(0, n - 2))

    def params(self, seeds: tuple = (), init: str | None = None) -> DICParams:
        """The DICParams of the controls with ``seeds`` ((x, y) image pixels) and
        the fields the panel does not show (:attr:`extra_params`); ``init``
        replaces the initial guess of the controls."""
        extra = dict(self._extra_params)
        if extra.get("search_max") is not None and extra["search_max"] < self.search.value:
            extra["search_max"] = int(self.search.value)  # the search cannot start wider
        return DICParams.from_dict({
            **extra, "method": self.method.value, "subset": int(self.subset.value),
            "step": int(self.step.value), "search": int(self.search.value),
            "refine": None if self.refine.value == "none" else self.refine.value,
            "smooth": self.smooth_value, "init": init or self.init.value, "seeds": seeds,
            "shape_function": self.shape_function.value})

    def summary(self) -> str:
        """The settings in words (for the log)."""
        return (tr("method {method}, subset {subset} px, step {step} px, search "
                   "{search} px, refinement {refine}, smoothing {smooth}, "
                   "init {init}; {reference}, frames {start}..{stop} every "
                   "{stride}").format(
                       method=self.method.value, subset=self.subset.value, step=self.step.value,
                       search=self.search.value, refine=self.refine.value,
                       smooth=self.smooth_value, init=self.init.value,
                       reference=self.reference.value, start=self.start.value,
                       stop=self.stop.value, stride=self.stride.value))

    # ------------------------------------------------------------ settings files
    def params_plan(self, params: DICParams, plan: Plan) -> dict[str, Any]:
        """Add the controls for ``params`` to ``plan``; return the fields the panel
        does not show that differ from the defaults (its next :attr:`extra_params`)."""
        put(plan, self.method, params.method, "method")
        put(plan, self.subset, params.subset, "subset")
        put(plan, self.step, params.step, "step")
        put(plan, self.search, params.search, "search")
        put(plan, self.refine, params.refine or "none", "refinement")
        put(plan, self.init, params.init, tr("initial guess"))
        put(plan, self.shape_function, params.shape_function, tr("subset shape"))
        if params.smooth == "auto":
            put(plan, self.smooth, "auto", tr("AL-DIC smoothing"))
        elif params.smooth == 0:
            put(plan, self.smooth, "off", tr("AL-DIC smoothing"))
        else:
            put(plan, self.smooth, "fixed", tr("AL-DIC smoothing"))
            put(plan, self.smooth_px, float(params.smooth), tr("smoothing length"))
        defaults = DICParams().to_dict()
        return {k: v for k, v in params.to_dict().items()
                if k not in PARAM_CONTROLS and k != "seeds" and v != defaults[k]}

    def tracking_plan(self, tracking: dict, plan: Plan, notes: list[str],
                      n_frames: int | None) -> None:
        """Add the controls for a "tracking" section (checked by
        :class:`~napari_aldic.engine.Settings`) to ``plan``; a frame range beyond
        the stack of ``n_frames`` frames is clamped (with a note)."""
        if "reference" in tracking:
            put(plan, self.reference, tracking["reference"], "tracking")
        if "stride" in tracking:
            put(plan, self.stride, tracking["stride"], tr("frame stride"))
        start, stop = tracking.get("start"), tracking.get("stop")
        if stop is None and "stop" in tracking:  # null: the last frame of the stack
            stop = int(self.stop.max)
        stack = (tr("the stack has {n_frames} frames").format(n_frames=n_frames) if n_frames
                 else tr("no image stack is chosen"))
        first = tr("the first frame {value} of the file is beyond the stack ({stack}); "
                   "using {max}")
        last = tr("the last frame {value} of the file is beyond the stack ({stack}); "
                  "using {max}")
        for value, spin, what in ((start, self.start, first), (stop, self.stop, last)):
            if value is None:
                continue
            if value > spin.max:
                # the "frame range:" label lets the settings panel find these notes
                notes.append(tr("frame range") + ": " + what.format(value=value, stack=stack,
                                                                      max=spin.max))
                value = int(spin.max)
            plan.append((spin, value))
