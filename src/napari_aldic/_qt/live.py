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
from .results import geometry_of, prepare

__all__ = ["LiveModel", "LivePanel", "LIVE_LAYER"]

#: name of the growing image layer of the frames
LIVE_LAYER = "Live frames"
#: milliseconds between looks at the watch's queue
TICK_MS = 150


class LiveModel:
    """A watch in a background thread and what it measured so far (no Qt).

    ``start(...)`` runs :func:`~napari_aldic.engine.watch`. The watch thread
    also computes each frame's strain and, given ``display``, the result
    layers' data (:func:`~.results.prepare`: the viewer's thread then only
    puts them in, however many frames there are). :meth:`drain` (main thread)
    takes the newest state (``analysis``, ``prepared``, ``files``) and returns
    whether anything new came; ``follow`` says whether the display should
    jump to the newest frame.
    """

    def __init__(self):
        self._thread: threading.Thread | None = None
        self._reset()

    def _reset(self) -> None:
        self.analysis: Analysis | None = None
        self.prepared = None
        self.files: list = []
        self.display = None  # the dock's display options, set by the panel
        self.geometry = None  # the frames layer's world transform, set by the panel
        self.follow = True
        self.error = ""
        self.report = None
        self.run_dir: Path | None = None
        self._work: tuple = ([], [])  # the watch thread's results and strains
        self._queue: queue.Queue = queue.Queue()
        self._stop = threading.Event()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def results(self) -> list:
        return [] if self.analysis is None else self.analysis.results

    @property
    def newest(self) -> int:
        return len(self.results) - 1

    def start(self, folder, run_dir, params, strain: StrainSettings,
              reference: str = "accumulative", display=None, **options) -> None:
        """Watch ``folder`` into ``run_dir`` (``options``: those of ``watch``)."""
        if self.running:
            raise RuntimeError("a watch is already running")
        self._reset()
        self.run_dir, self.display = Path(run_dir), display
        self._setup = (params, strain, reference)

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
        """Watch thread: frame ``k`` is on disk; its strain and layer data are made here."""
        params, s, reference = self._setup
        results, strains = self._work
        if not results:  # frame 0, the reference: its zero field from the run folder
            ref = load_result(self.run_dir / "frame_00000.npz")
            results.append(ref)
            strains.append(compute_strain(ref, window=s.window, method=s.method,
                                          measure=s.measure))
        while len(results) <= k:
            results.append(None)
            strains.append(None)
        results[k] = res
        strains[k] = compute_strain(res, window=s.window, method=s.method, measure=s.measure)
        n = len(results)
        analysis = Analysis(list(results), list(strains), list(range(n)), n, params, reference,
                            s, source=str(self.run_dir))
        display, geometry = self.display, self.geometry
        prepared = None if display is None or geometry is None else \
            prepare(analysis, geometry, display)
        self._queue.put((analysis, prepared, list(info["files"])))

    def stop(self) -> None:
        self._stop.set()

    def drain(self) -> bool:
        """Take the newest queued state (main thread); True when something
        new came (a frame, or the end of the watch)."""
        new = False
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return new
            new = True
            if item is not None:
                self.analysis, self.prepared, self.files = item

    def user_moved(self, frame: int) -> None:
        """The user moved the time slider to ``frame``: follow only on the newest."""
        self.follow = frame >= self.newest


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
        self._run = None  # the dock's RunPanel (watch_run): one analysis at a time
        super().__init__(labels=True)

    def watch_run(self, run_panel) -> None:
        """Share the dock's run status with ``run_panel``: while a run runs Start is
        disabled, while the watch runs the run status says so and Run is disabled."""
        self._run = run_panel
        run_panel.running_changed.connect(
            lambda running: setattr(self.start_button, "enabled",
                                    not running and not self.model.running))

    def _say_live(self, live: bool) -> None:
        self.start_button.enabled, self.stop_button.enabled = not live, live
        if self._run is not None:
            self._run.set_live(live)

    def _setup_ui(self) -> None:
        self.folder = FileEdit(mode="d", label=tr("Camera folder"))
        self.run_dir = FileEdit(mode="d", label=tr("Run folder"))
        for edit in (self.folder, self.run_dir):  # magicgui's own button text is English
            edit.choose_btn.text = tr("Choose folder...")
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
        if self._run is not None and self._run.running:
            self.state.value = tr("An analysis is running: start live when it has ended.")
            return
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
        self.model.start(folder, run, params, strain, reference, display=self._display())
        self._say_live(True)
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
            self._say_live(False)
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
        if m.analysis is not None and len(m.results) > 1:
            self._results.analysis, self._results.image = m.analysis, layer
            display = m.display = self._display()  # a change applies from the next frame
            if m.prepared is not None and m.prepared.display == display:
                for _ in self._results.steps(m.prepared):  # made in the watch thread
                    pass
            else:
                self._results.show(display, layer)
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
        layer = self._viewer.add_image(data, name=LIVE_LAYER, colormap="gray")
        self.model.geometry = geometry_of(layer)  # the watch thread's result layers follow it
        return layer

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
