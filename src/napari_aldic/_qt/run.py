"""The Run panel: input status, Run/Cancel, progress, time left and the log.

A run is a :class:`~napari_aldic._analysis.Job` executed by
:func:`~napari_aldic._analysis.run_in_thread` in a napari generator worker:
progress reports arrive on the main thread (``yielded``), the
:class:`~napari_aldic._analysis.Analysis` through ``returned``, an error
through ``errored`` (one notification, the viewer stays usable).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from magicgui.widgets import Container, Label, ProgressBar, PushButton, TextEdit
from psygnal import Signal

from .._analysis import Analysis, Job, run_in_thread
from .controls import Panel

__all__ = ["RunPanel", "format_seconds"]


def format_seconds(s: float) -> str:
    """``m:ss``, or ``h:mm:ss`` from one hour."""
    s = max(0, int(round(s)))
    if s >= 3600:
        return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"
    return f"{s // 60}:{s % 60:02d}"


class RunPanel(Panel):
    """Status line, Run and Cancel buttons, progress bar, frames/time left, log.

    Signals
    -------
    run_requested
        The Run button was clicked.
    running_changed(bool)
        A run started or ended.

    Attributes
    ----------
    show_results : callable(Analysis), optional
        Called with every finished (or cancelled) run's analysis; an exception
        is reported as "could not show the results".
    """

    run_requested = Signal()
    running_changed = Signal(bool)

    def __init__(self):
        self.show_results: Callable[[Analysis], None] | None = None
        self._running = False
        self._worker = None
        self._cancel = threading.Event()
        self._t0 = 0.0
        self._n_deformed = 0
        super().__init__(labels=False, margins=None)

    def _setup_ui(self) -> None:
        self.status = Label(value="")
        self.run_button = PushButton(text="Run")
        self.cancel_button = PushButton(text="Cancel", enabled=False)
        self.progress = ProgressBar(value=0, min=0, max=1000, label="")
        self.eta = Label(value="", label="")
        self.log = TextEdit(value="", label="")
        self.log.read_only = True
        buttons = Container(widgets=[self.run_button, self.cancel_button], layout="horizontal",
                            labels=False)
        self.extend([self.status, buttons, self.progress, self.eta, self.log])
        self.status.native.setWordWrap(True)
        self.eta.native.setWordWrap(True)
        self.log.native.setMinimumHeight(90)
        self.log.native.setMaximumHeight(170)

    def _setup_callbacks(self) -> None:
        self.run_button.changed.connect(self.run_requested.emit)
        self.cancel_button.changed.connect(self.cancel)

    # ------------------------------------------------------------ state
    @property
    def running(self) -> bool:
        """Whether a run is in progress."""
        return self._running

    def _set_running(self, running: bool) -> None:
        self._running = running
        self.cancel_button.enabled = running
        self.running_changed.emit(running)

    def show_problems(self, errors: list[str], warnings: list[str]) -> None:
        """Show the input check in the status line; Run is enabled without errors."""
        lines = [f"<span style='color:#ff6b6b'>&#9888; {e}</span>" for e in errors]
        lines += [f"<span style='color:#f0c040'>{w}</span>" for w in warnings]
        if not errors:
            lines.insert(0, "<span style='color:#6bd66b'>Ready.</span>")
        self.status.value = "<br>".join(lines)
        self.run_button.enabled = not errors and not self._running

    def write_log(self, text: str) -> None:
        """Append a time-stamped line to the log (scrolled to the end)."""
        stamp = time.strftime("%H:%M:%S")
        self.log.value = (self.log.value + "\n" if self.log.value else "") + f"[{stamp}] {text}"
        bar = self.log.native.verticalScrollBar()
        bar.setValue(bar.maximum())

    # ------------------------------------------------------------ running
    def start(self, job: Job) -> None:
        """Run ``job`` in a worker thread (no-op while one runs)."""
        from napari.qt.threading import create_worker
        from superqt.utils import GeneratorWorker

        if self._running:
            return
        self._cancel.clear()
        self._n_deformed = job.n_deformed
        self.write_log(f"Run {time.strftime('%H:%M:%S')}: {job.summary}")
        # superqt's plain worker: errors reach _on_errored only (one notification)
        worker = create_worker(run_in_thread, job, self._cancel,
                               _worker_class=GeneratorWorker, _ignore_errors=True)
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
        if self._running:
            self._cancel.set()
            self.cancel_button.enabled = False
            self.eta.value = "cancelling after the current frame ..."
            self.write_log("Cancel requested: stopping after the current frame.")

    def stopper(self) -> Callable[[], None]:
        """A function that asks a run to stop after its frame (the widget is
        closed); it works while the panel is torn down."""
        return self._cancel.set

    def _on_progress(self, item) -> None:
        frame, frac, msg = item
        frac = float(min(max(frac, 0.0), 1.0))
        self.progress.value = int(round(1000 * frac))
        done = int(round(frac * self._n_deformed))
        elapsed = time.perf_counter() - self._t0
        left = (f" · about {format_seconds(elapsed * (1 - frac) / frac)} left"
                if 0 < frac < 1 else "")
        if not self._cancel.is_set():
            self.eta.value = (f"{done}/{self._n_deformed} frames · "
                              f"{format_seconds(elapsed)} elapsed{left}")
        if "done" in msg or "strain" in msg:
            self.write_log(msg)

    def _on_returned(self, analysis: Analysis) -> None:
        from napari.utils.notifications import show_error, show_info

        done = analysis.n_done - 1
        state = "cancelled" if analysis.cancelled else "finished"
        self.write_log(f"{state} in {analysis.seconds:.1f} s: {done}/"
                       f"{len(analysis.frames) - 1} frames computed")
        last = next((r for r in reversed(analysis.results) if r is not None), None)
        if last is not None and done > 0:
            self.write_log(last.summary())
        try:
            if self.show_results is not None:
                self.show_results(analysis)
        except Exception as exc:  # never crash the viewer on a display problem
            show_error(f"napari-aldic: could not show the results: {exc}")
            self.write_log(f"ERROR showing results: {exc}")
            return
        self.eta.value = (f"{done}/{len(analysis.frames) - 1} frames · {state} in "
                          f"{format_seconds(analysis.seconds)}")
        if analysis.cancelled:
            show_info(f"napari-aldic: cancelled; {done} finished frame(s) kept")

    def _on_errored(self, exc: BaseException) -> None:
        from napari.utils.notifications import show_error

        msg = str(exc) or exc.__class__.__name__
        self.write_log(f"ERROR: {msg}")
        self.eta.value = "failed (see log)"
        show_error(f"napari-aldic: {msg}")

    def _on_finished(self) -> None:
        self._worker = None
        self._set_running(False)
