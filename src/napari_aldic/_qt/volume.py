"""The dock's "Volume (DVC)" section: correlate two volumes (engine ``correlate_volume``).

:class:`VolumeChoice` (no Qt) holds what the panel's controls say and turns
it into the engine's inputs: a volume is a 3-D image layer, or one volume of a
4-D (t, z, y, x) layer chosen by index; the optional ROI is a 3-D Labels layer
(non-zero voxels are material). :class:`VolumePanel` runs the correlation in
a napari generator worker, so the viewer never waits, and adds the result as
the layers of :func:`~napari_aldic._volume_layers.volume_layers`. Cancel frees
the panel at once, drops the result and sets the engine's stop request: the
computation ends in the background at its next batch of nodes.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from magicgui.widgets import ComboBox, Container, Label, PushButton, SpinBox

from .._volume_layers import auto_vector_scale, volume_layers
from ..engine import DICParams, compute_strain_volume, correlate_volume
from ..i18n import tr
from . import warmup
from .controls import Panel

__all__ = ["VolumeChoice", "VolumePanel", "volume_of", "roi_of", "placed", "VOLUME_META"]

#: metadata key marking the layers of a volume result
VOLUME_META = "napari_aldic_volume"
_DEFAULTS = DICParams()


def volume_of(data, index: int, what: str) -> np.ndarray:
    """The (z, y, x) volume of a layer's ``data``: itself when 3-D, ``data[index]``
    when 4-D (t, z, y, x); ``ValueError`` naming ``what`` otherwise."""
    shape = tuple(data.shape)
    if len(shape) == 3:
        return np.asarray(data)
    if len(shape) == 4:
        if not 0 <= index < shape[0]:
            raise ValueError(tr("{what}: volume index {index} is outside 0..{last}").format(
                what=what, index=index, last=shape[0] - 1))
        return np.asarray(data[index])
    raise ValueError(tr("{what} must be a 3-D volume or a 4-D (t, z, y, x) stack; it has "
                        "shape {shape}").format(what=what, shape=shape))


def roi_of(labels, shape) -> np.ndarray | None:
    """The material mask of a 3-D Labels layer's data (``None`` for no ROI)."""
    if labels is None:
        return None
    mask = np.asarray(labels) != 0
    if mask.shape != tuple(shape):
        raise ValueError(tr("the ROI labels have shape {roi} but the volumes {shape}").format(
            roi=mask.shape, shape=tuple(shape)))
    if not mask.any():
        raise ValueError(tr("the ROI labels are empty (no non-zero voxel)"))
    return mask


@dataclass
class VolumeChoice:
    """The panel's choices (layers as objects with ``.data`` and ``.name``)."""

    reference: object = None
    deformed: object = None
    ref_index: int = 0
    def_index: int = 1
    roi: object = None
    subset: int = _DEFAULTS.subset
    step: int = _DEFAULTS.step
    method: str = _DEFAULTS.method

    def inputs(self):
        """``(ref, dfm, roi, params)`` for :func:`correlate_volume`; ``ValueError``
        with a one-line reason when the choices make no correlation."""
        if self.reference is None or self.deformed is None:
            raise ValueError(tr("Choose a reference and a deformed volume first."))
        ref = volume_of(self.reference.data, self.ref_index, self.reference.name)
        dfm = volume_of(self.deformed.data, self.def_index, self.deformed.name)
        if self.reference is self.deformed and self.ref_index == self.def_index:
            raise ValueError(tr("The reference and deformed volumes are the same volume."))
        if ref.shape != dfm.shape:
            raise ValueError(tr("The volumes differ in shape: {a} and {b}").format(
                a=ref.shape, b=dfm.shape))
        roi = roi_of(None if self.roi is None else self.roi.data, ref.shape)
        params = DICParams(subset=self.subset, step=self.step, method=self.method)
        return ref, dfm, roi, params


def placed(kwargs: dict, scale, translate) -> dict:
    """``kwargs`` of a result layer (in voxels) put on a source layer of world
    ``scale``/``translate`` (z, y, x): a voxel of the result is that voxel of the source."""
    scale, translate = np.asarray(scale, float), np.asarray(translate, float)
    own = np.asarray(kwargs.get("scale", (1.0, 1.0, 1.0)), float)
    shift = np.asarray(kwargs.get("translate", (0.0, 0.0, 0.0)), float)
    return {**kwargs, "scale": tuple(scale * own), "translate": tuple(translate + scale * shift),
            "axis_labels": ("z", "y", "x")}


def _correlate(ref, dfm, roi, params, stop=None):
    """Worker thread: the correlation, then the layers' data (the viewer only adds them).
    ``stop`` (a threading.Event) set by Cancel ends the correlation at its next
    batch of nodes (it raises ``Cancelled``, which nobody listens to by then)."""
    warmup.wait()  # the dock's engine warm-up first: parallel kernels one thread at a time
    yield  # a cancellation point before the long call
    res = correlate_volume(ref, dfm, roi, params=params, cancel=stop)
    yield
    try:
        strain = compute_strain_volume(res)
    except ValueError:  # e.g. too few nodes for the strain window: displacement only
        strain = None
    return res, volume_layers(res, auto_vector_scale(res), strain)


class VolumePanel(Panel):
    """Volumes, ROI, subset/step/method, Run/Cancel and a one-line state."""

    def __init__(self, viewer):
        self._viewer = viewer
        self._worker = None
        self._stop = threading.Event()
        self._placement = ((1.0, 1.0, 1.0), (0.0, 0.0, 0.0))
        #: the last result shown (a :class:`~napari_aldic.engine.VolumeResult`)
        self.result = None
        super().__init__(labels=True)

    def _setup_ui(self) -> None:
        self.reference = ComboBox(label=tr("Reference volume"), choices=self._volume_layers)
        self.ref_index = SpinBox(label=tr("its index (4-D)"), value=0, min=0, max=100_000)
        self.deformed = ComboBox(label=tr("Deformed volume"), choices=self._volume_layers)
        self.def_index = SpinBox(label=tr("its index (4-D)"), value=1, min=0, max=100_000)
        self.roi = ComboBox(label=tr("ROI (3-D labels)"), choices=self._roi_layers)
        self.subset = SpinBox(label=tr("Subset (voxels)"), value=_DEFAULTS.subset, min=7,
                              max=255, step=2)
        self.step = SpinBox(label=tr("Step (voxels)"), value=_DEFAULTS.step, min=1, max=128)
        self.method = ComboBox(label=tr("Method"), value=_DEFAULTS.method,
                               choices=[(tr("Local (IC-GN)"), "local"), (tr("AL-DVC"), "aldic")])
        self.run_button = PushButton(text=tr("Run volume"))
        self.cancel_button = PushButton(text=tr("Cancel"), enabled=False)
        self.state = Label(value=tr("Choose two volumes (3-D image layers)."))
        self.state.native.setWordWrap(True)  # a long message never widens the dock
        buttons = Container(layout="horizontal", labels=False,
                            widgets=[self.run_button, self.cancel_button])
        buttons.margins = (0, 0, 0, 0)
        self.extend([self.reference, self.ref_index, self.deformed, self.def_index, self.roi,
                     self.subset, self.step, self.method, buttons, self.state])

    def _setup_callbacks(self) -> None:
        self.run_button.changed.connect(self.run)
        self.cancel_button.changed.connect(self.cancel)
        events = self._viewer.layers.events
        for event in (events.inserted, events.removed):
            event.connect(self._refresh)
        self.native.destroyed.connect(lambda *_: (self._disconnect(events), self._unhook()))
        self._refresh()

    def _disconnect(self, events) -> None:
        for event in (events.inserted, events.removed):
            event.disconnect(self._refresh)

    # ------------------------------------------------------------ choices
    def _volume_layers(self, *_) -> list:
        return [(lay.name, lay) for lay in self._viewer.layers
                if type(lay).__name__ == "Image" and lay.ndim in (3, 4)
                and not lay.metadata.get(VOLUME_META) and not getattr(lay, "rgb", False)]

    def _roi_layers(self, *_) -> list:
        return [(tr("(none)"), None)] + [(lay.name, lay) for lay in self._viewer.layers
                                         if type(lay).__name__ == "Labels" and lay.ndim == 3]

    def _refresh(self, *_) -> None:
        try:
            for box in (self.reference, self.deformed, self.roi):
                box.reset_choices()
        except RuntimeError:  # the panel was closed meanwhile
            return
        volumes = [lay for _, lay in self._volume_layers()]
        if len(volumes) >= 2 and self.deformed.value is self.reference.value \
                and self.reference.value.ndim == 3:
            self.deformed.value = next(v for v in volumes if v is not self.reference.value)

    @property
    def choice(self) -> VolumeChoice:
        return VolumeChoice(self.reference.value, self.deformed.value, int(self.ref_index.value),
                            int(self.def_index.value), self.roi.value, int(self.subset.value),
                            int(self.step.value), self.method.value)

    # ------------------------------------------------------------ running
    @property
    def running(self) -> bool:
        return self._worker is not None

    def run(self, *_) -> None:
        """Start the correlation in a worker thread (no-op while one runs)."""
        from napari.qt.threading import create_worker
        from superqt.utils import GeneratorWorker

        if self.running:
            return
        try:
            ref, dfm, roi, params = self.choice.inputs()
        except ValueError as exc:
            self.state.value = str(exc)
            return
        self._stop = threading.Event()
        worker = create_worker(_correlate, ref, dfm, roi, params, self._stop,
                               _worker_class=GeneratorWorker, _ignore_errors=True)
        worker.returned.connect(self._on_returned)
        worker.errored.connect(self._on_errored)
        source = self.reference.value  # the results go where its voxels are
        self._placement = (tuple(source.scale)[-3:], tuple(source.translate)[-3:])
        self._worker = worker
        self._set_running(True)
        self.state.value = tr("Correlating {shape} voxels (subset {subset}, step {step})..."
                              ).format(
            shape=" x ".join(str(n) for n in ref.shape), subset=params.subset, step=params.step)
        worker.start()

    def cancel(self, *_) -> None:
        """Stop the running correlation (at its next batch of nodes, in the
        background) and drop its result."""
        if self._worker is None:
            return
        self._forget()
        self.state.value = tr("Cancelled: the correlation ends in the background and its "
                              "result is dropped.")

    def _forget(self) -> None:
        self._unhook()
        self._set_running(False)

    def _unhook(self) -> None:
        """Stop listening to the worker (asked to quit): its result goes nowhere."""
        worker, self._worker = self._worker, None
        if worker is None:
            return
        self._stop.set()  # the engine stops at its next batch of nodes
        worker.quit()
        for signal, slot in ((worker.returned, self._on_returned),
                             (worker.errored, self._on_errored)):
            try:
                signal.disconnect(slot)
            except (TypeError, RuntimeError):
                pass

    def _set_running(self, running: bool) -> None:
        self.run_button.enabled, self.cancel_button.enabled = not running, running

    def _on_returned(self, value) -> None:
        self._forget()
        if value is None:  # quit at a cancellation point
            return
        res, layers = value
        self.result = res
        for data, kwargs, kind in layers:
            kwargs = {**placed(kwargs, *self._placement), "metadata": {VOLUME_META: True},
                      "name": "DVC " + kwargs["name"]}  # beside the 2-D "DIC u" ...
            getattr(self._viewer, f"add_{kind}")(data, **kwargs)
        self.state.value = tr("Done: {n} nodes, {trusted} trusted, in {seconds:.1f} s.").format(
            n=len(res), trusted=res.n_valid, seconds=res.meta["timing"]["total"])

    def _on_errored(self, exc) -> None:
        self._forget()
        text = " ".join(str(exc).split()) or type(exc).__name__
        self.state.value = tr("Volume correlation failed: {error}").format(error=text)
