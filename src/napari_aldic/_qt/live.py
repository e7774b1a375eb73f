"""The dock's "Live" mode: watch a folder a camera writes into (engine ``watch``).

:class:`LiveModel` (no Qt) runs the watch in a thread and queues each frame's
result and strain; :class:`LivePanel` drains that queue on a timer in the
main thread, so the viewer never waits for a correlation: the frames image
layer grows (a lazy stack of the frame files), the result layers (and with
them the probe and stress-strain plots) are updated, and the time slider
follows the newest frame until the user moves it (back on the newest frame,
it follows again). Stop ends the watch; the run folder is then a normal run
folder (open it with the reader, export it, resume it with ``napari-aldic
watch``).
"""

from __future__ import annotations

import queue
import threading
from pathlib import Path

import numpy as np
from magicgui.widgets import Container, FileEdit, Label, PushButton

from .._analysis import Analysis, StrainSettings
from ..engine import compute_strain, load_result, watch
from ..i18n import tr
from .controls import Panel

__all__ = ["LiveModel", "LivePanel", "LIVE_LAYER"]

#: name of the growing image layer of the frames
LIVE_LAYER = "Live frames"
#: milliseconds between looks at the watch's queue
TICK_MS = 150


class LiveModel:
    """A watch in a background thread and what it measured so far (no Qt).

    ``start(...)`` runs :func:`~napari_aldic.engine.watch`; :meth:`drain`
    (main thread) moves the queued frames into ``results``/``strains``/
    ``files`` and returns whether anything new came; ``follow`` says whether
    the display should jump to the newest frame.
    """

    def __init__(self):
        self._thread: threading.Thread | None = None
        self._reset()

    def _reset(self) -> None:
        self.results: list = []
        self.strains: list = []
        self.files: list = []
        self.params = None
        self.strain = StrainSettings()
        self.reference = "accumulative"
        self.follow = True
        self.error = ""
        self.report = None
        self.run_dir: Path | None = None
        self._queue: queue.Queue = queue.Queue()
        self._stop = threading.Event()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def newest(self) -> int:
        return len(self.results) - 1

    def start(self, folder, run_dir, params, strain: StrainSettings,
              reference: str = "accumulative", **options) -> None:
        """Watch ``folder`` into ``run_dir`` (``options``: those of ``watch``)."""
        if self.running:
            raise RuntimeError("a watch is already running")
        self._reset()
        self.params, self.strain, self.reference = params, strain, reference
        self.run_dir = Path(run_dir)

        def target():
            try:
                self.report = watch(folder, run_dir, params=params, reference=reference,
                                    on_frame=self._measured, stop=self._stop.is_set,
                                    **options)
            except Exception as exc:  # shown in the panel; the folder keeps what is done
                self.error = str(exc) or type(exc).__name__
            finally:
                self._queue.put(None)

        self._thread = threading.Thread(target=target, name="napari-aldic watch", daemon=True)
        self._thread.start()

    def _measured(self, k: int, res, info: dict) -> None:
        """Watch thread: frame ``k`` is on disk; its strain is computed here too."""
        s = self.strain
        strain = compute_strain(res, window=s.window, method=s.method, measure=s.measure)
        self._queue.put((k, res, strain, list(info["files"])))

    def stop(self) -> None:
        self._stop.set()

    def drain(self) -> bool:
        """Take the queued frames (main thread); True when something new came
        (a frame, or the end of the watch)."""
        new = False
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return new
            new = True
            if item is None:
                continue
            k, res, strain, files = item
            self.files = files
            if not self.results:  # frame 0, the reference: its zero field from the folder
                ref = load_result(self.run_dir / "frame_00000.npz")
                self.results, self.strains = [ref], [compute_strain(ref)]
            while len(self.results) <= k:
                self.results.append(None)
                self.strains.append(None)
            self.results[k], self.strains[k] = res, strain

    def user_moved(self, frame: int) -> None:
        """The user moved the time slider to ``frame``: follow only on the newest."""
        self.follow = frame >= self.newest

    def analysis(self) -> Analysis | None:
        """The frames so far as the dock shows an analysis (None before frame 1)."""
        if len(self.results) < 2:
            return None
        n = len(self.results)
        return Analysis(list(self.results), list(self.strains), list(range(n)), n,
                        self.params, self.reference, self.strain, source=str(self.run_dir))


def frames_stack(files: list, first: np.ndarray):
    """The frame files as a lazy (T, H, W) dask stack (each read when shown)."""
    import dask
    import dask.array as da

    from ..engine.io import read_image

    parts = [da.from_delayed(dask.delayed(read_image)(str(p)), first.shape, first.dtype)
             for p in files]
    return da.stack(parts)


class LivePanel(Panel):
    """Folder, run folder, Start/Stop and the live status (see the module text).

    ``settings()`` gives the dock's ``(params, strain settings dict, reference)``,
    ``display()`` its display options; ``results`` is the dock's
    :class:`~.results.ResultLayers`, which shows the frames as an analysis.
    """

    def __init__(self, viewer, settings, display, results):
        self._viewer, self._settings, self._display, self._results = (
            viewer, settings, display, results)
        self.model = LiveModel()
        self._moving = False
        self._first = None
        super().__init__(labels=True)

    def _setup_ui(self) -> None:
        self.folder = FileEdit(mode="d", label=tr("Camera folder"))
        self.run_dir = FileEdit(mode="d", label=tr("Run folder"))
        self.start_button = PushButton(text=tr("Start live"))
        self.stop_button = PushButton(text=tr("Stop"), enabled=False)
        self.state = Label(value=tr("Not watching."))
        buttons = Container(layout="horizontal", labels=False,
                            widgets=[self.start_button, self.stop_button])
        buttons.margins = (0, 0, 0, 0)
        self.extend([self.folder, self.run_dir, buttons, self.state])

    def _setup_callbacks(self) -> None:
        from qtpy.QtCore import QTimer

        self.start_button.changed.connect(self.start)
        self.stop_button.changed.connect(self.stop)
        self._timer = QTimer()
        self._timer.setInterval(TICK_MS)
        self._timer.timeout.connect(self.tick)
        self._viewer.dims.events.current_step.connect(self._on_step)
        self.native.destroyed.connect(lambda *_: self.model.stop())

    def start(self, *_) -> None:
        """Start watching the chosen folder into the run folder."""
        folder, run = Path(self.folder.value), Path(self.run_dir.value)
        if str(self.folder.value) in ("", ".") or str(self.run_dir.value) in ("", "."):
            self.state.value = tr("Choose the camera folder and a run folder first.")
            return
        try:
            params, strain, reference = self._settings()
        except ValueError as exc:  # the controls do not make valid settings
            self.state.value = str(exc)
            return
        strain = StrainSettings(**{k: v for k, v in (strain or {}).items()
                                   if k in ("window", "method", "measure")})
        self._first = None
        self.model.start(folder, run, params, strain, reference)
        self.start_button.enabled, self.stop_button.enabled = False, True
        self.state.value = tr("Watching {folder} (waiting for frames)...").format(folder=folder)
        self._timer.start()

    def stop(self, *_) -> None:
        """End the watch (a frame being correlated is dropped; rerun resumes it)."""
        self.model.stop()
        self.state.value = tr("Stopping...")

    def tick(self) -> None:
        """Main thread: show what the watch measured since the last tick."""
        if not self.model.drain():
            return
        if self.model.files:
            self._show()
        if not self.model.running:
            self._timer.stop()
            self.start_button.enabled, self.stop_button.enabled = True, False
            self.state.value = self._final_words()

    def _show(self) -> None:
        self._moving = True  # dims events of the layers' update are not the user's
        try:
            self._update()
        finally:
            self._moving = False

    def _update(self) -> None:
        m = self.model
        layer = self._frames_layer()
        analysis = m.analysis()
        if analysis is not None:
            self._results.analysis, self._results.image = analysis, layer
            self._results.show(self._display(), layer)
        self.state.value = tr("Live: frame {k} of {folder}, {trusted:.0%} of the nodes "
                              "trusted").format(k=m.newest, folder=Path(self.folder.value).name,
                                                trusted=m.results[-1].n_valid /
                                                max(len(m.results[-1]), 1))
        if m.follow:
            self._go_to(m.newest)

    def _frames_layer(self):
        """The growing image layer of the frame files (added on the first frame)."""
        files = self.model.files
        if self._first is None:
            from ..engine.io import read_image

            self._first = read_image(files[0])
        data = frames_stack(files, self._first)
        if LIVE_LAYER in self._viewer.layers:
            layer = self._viewer.layers[LIVE_LAYER]
            layer.data = data
            return layer
        return self._viewer.add_image(data, name=LIVE_LAYER, colormap="gray")

    def _go_to(self, k: int) -> None:
        self._viewer.dims.set_point(0, float(k))

    def _on_step(self, *_) -> None:
        if self._moving or not self.model.results or self._viewer.dims.ndim < 3:
            return
        self.model.user_moved(int(round(float(self._viewer.dims.point[0]))))

    def _final_words(self) -> str:
        m = self.model
        if m.error:
            return tr("The watch stopped: {error}").format(error=m.error)
        return tr("Watch ended: {n} frame(s) in {run} (open it as a normal analysis; the "
                  "same folders resume the watch).").format(n=max(len(m.results) - 1, 0),
                                                            run=self.run_dir.value)
