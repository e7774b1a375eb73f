"""The Run panel: input status, Run/Cancel, progress, time elapsed and left, and the log.

A run is a :class:`~napari_aldic._analysis.Job` executed by
:func:`~napari_aldic._analysis.run_in_thread` in a napari generator worker:
progress reports arrive on the main thread (``yielded``), the
:class:`~napari_aldic._analysis.Analysis` (with the result layers made in the
worker) through ``returned``, an error through ``errored`` (one notification,
the viewer stays usable). The result layers are then put in the viewer one per
turn of the event loop, so that the viewer never stalls; the run counts as
running until they are all there.

The log (:attr:`RunPanel.log`) is made here but placed by the dock widget.
"""

from __future__ import annotations

import gc
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from magicgui.widgets import Container, Label, ProgressBar, PushButton, TextEdit
from psygnal import Signal

from .._analysis import Analysis, Job, run_in_thread
from ..engine import is_compiling
from ..i18n import ntr, tr, tr_noop
from .controls import Panel
from .explain import result_summary, with_explanation

__all__ = ["RunPanel", "format_seconds", "PREPARING"]

#: pause between two steps of showing the results (one layer each), in ms
STEP_PAUSE_MS = 15
#: pause after a step that made a layer visible (it is drawn for the first time), ms
DRAW_PAUSE_MS = 50
#: said while the Numba kernels are compiled or loaded (the first run of a new install)
PREPARING = tr_noop("Preparing the correlation engine (first run only)…")
#: said while Numba compiles a kernel during a run (a first run, or a new case)
COMPILING = tr_noop("compiling kernels (first run only)")
#: the status line while a run computes or shows its results
RUNNING = tr_noop("Running…")
LIVE = tr_noop("Live analysis running: Run is disabled until the watch stops.")
#: progress events written to the log (the others move the bar only)
LOGGED_STAGES = ("frame_done", "frame_loaded", "stopped", "strain")


def format_seconds(s: float) -> str:
    """``m:ss``, or ``h:mm:ss`` from one hour."""
    s = max(0, int(round(s)))
    if s >= 3600:
        return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"
    return f"{s // 60}:{s % 60:02d}"


class RunPanel(Panel):
    """Status line, Run and Cancel buttons, progress bar, frames and time.

    Signals
    -------
    run_requested
        The Run button was clicked.
    running_changed(bool)
        A run started or ended (its result layers all shown).

    Attributes
    ----------
    show_results : callable(Analysis, prepared) -> iterator, optional
        Called with every finished (or cancelled) run's analysis and what
        ``after`` made of it in the worker; each step of the iterator it
        returns runs in its own turn of the event loop. An exception is
        reported as "could not show the results".
    preparing : bool
        The correlation engine is being prepared (said in the status line).
    """

    run_requested = Signal()
    running_changed = Signal(bool)

    def __init__(self):
        self.show_results: Callable[[Analysis, Any], Iterator | None] | None = None
        self.preparing = False
        self._running = False
        self.live = False  # a live watch analyses: no run beside it (set_live)
        self._worker = None
        self._worker_done = True
        self._steps: Iterator | None = None
        self._cancel = threading.Event()
        self._t0 = 0.0
        self._frac = 0.0
        self._eta: tuple | None = None  # (seconds left, when the engine said so)
        self._n_deformed, self._units = 0, None  # the running job's frame count and units
        self._problems: tuple[list, list] = ([], [])
        #: each step of showing the last run's results: (start, end) in
        #: ``time.perf_counter`` seconds and the main thread's CPU seconds in it
        self.display_steps: list[tuple[float, float, float]] = []
        super().__init__(labels=False, margins=None)

    def _setup_ui(self) -> None:
        from qtpy.QtCore import QTimer

        self.status = Label(value="")
        self.run_button = PushButton(text=tr("Run"))
        self.cancel_button = PushButton(text=tr("Cancel"), enabled=False)
        self.progress = ProgressBar(value=0, min=0, max=1000, label="")
        self.eta = Label(value="", label="")
        self.log = TextEdit(value="", label="")
        self.log.read_only = True
        buttons = Container(widgets=[self.run_button, self.cancel_button], layout="horizontal",
                            labels=False)
        buttons.margins = (0, 0, 0, 0)
        self.extend([self.status, buttons, self.progress, self.eta])
        from qtpy.QtWidgets import QSizePolicy

        for label in (self.status, self.eta):
            label.native.setWordWrap(True)  # every line shown: the label grows, not clips
            label.native.setSizePolicy(QSizePolicy.Policy.Preferred,
                                       QSizePolicy.Policy.Minimum)
            label.native.setMinimumWidth(120)
        self.log.native.setMinimumHeight(80)
        self._clock = QTimer(self.native)
        self._clock.setInterval(500)  # elapsed time moves between frames too
        # the next display step: a timer owned by the panel dies with it (a bare
        # singleShot would call into a closed panel and abort napari)
        self._step_timer = QTimer(self.native)
        self._step_timer.setSingleShot(True)
        self._closed = False
        self._final = ""

    def _setup_callbacks(self) -> None:
        self.run_button.changed.connect(self.run_requested.emit)
        self.cancel_button.changed.connect(self.cancel)
        self._clock.timeout.connect(self._show_time)
        self._step_timer.timeout.connect(lambda: self._drive(self._final))

    # ------------------------------------------------------------ state
    @property
    def running(self) -> bool:
        """Whether a run is in progress (its result layers not all shown yet)."""
        return self._running

    def _set_running(self, running: bool) -> None:
        self._running = running
        self.cancel_button.enabled = running
        if running:
            self._clock.start()
        else:
            self._clock.stop()
        self.running_changed.emit(running)

    def show_problems(self, errors: list[str], warnings: list[str]) -> None:
        """Show the input check in the status line; Run is enabled without errors."""
        self._problems = (list(errors), list(warnings))
        lines = [f"<span style='color:#ff6b6b'>&#9888; {e}</span>" for e in errors]
        lines += [f"<span style='color:#f0c040'>{w}</span>" for w in warnings]
        if self._running or self.live:  # never "Ready." while an analysis computes
            lines.insert(0, "<span style='color:#8ab4f8'>" + tr(LIVE if self.live else RUNNING)
                         + "</span>")
        elif not errors:
            lines.insert(0, "<span style='color:#6bd66b'>" + tr("Ready.") + "</span>")
        if self.preparing:
            lines.insert(0, f"<span style='color:#8ab4f8'>{tr(PREPARING)}</span>")
        self.status.value = "<br>".join(lines)
        self.run_button.enabled = not errors and not self._running and not self.live

    def set_live(self, live: bool) -> None:
        """Say that a live watch runs (Run disabled), or that it ended."""
        self.live = live
        self.show_problems(*self._problems)

    def set_preparing(self, preparing: bool) -> None:
        """Say (or stop saying) that the correlation engine is being prepared."""
        self.preparing = preparing
        self.show_problems(*self._problems)
        if self._running and self._frac == 0:
            self._show_time()

    def write_log(self, text: str) -> None:
        """Append a time-stamped line to the log (scrolled to the end)."""
        stamp = time.strftime("%H:%M:%S")
        self.log.value = (self.log.value + "\n" if self.log.value else "") + f"[{stamp}] {text}"
        bar = self.log.native.verticalScrollBar()
        bar.setValue(bar.maximum())

    # ------------------------------------------------------------ running
    def start(self, job: Job, after: Callable[[Analysis], Any] | None = None,
              before: Callable[[], Any] | None = None) -> None:
        """Run ``job`` in a worker thread (no-op while one runs); ``before`` runs
        first in that thread, ``after`` on its analysis, and its outcome goes to
        :attr:`show_results`."""
        from napari.qt.threading import create_worker
        from superqt.utils import GeneratorWorker

        if self._running:
            return
        if after is not None:
            after = _frozen_gc(after)
        self._cancel.clear()
        self._n_deformed, self._units = job.n_deformed, job.units
        self.write_log(tr("Run {time}: {summary}").format(time=time.strftime('%H:%M:%S'),
                                                         summary=job.summary))
        # superqt's plain worker: errors reach _on_errored only (one notification)
        worker = create_worker(run_in_thread, job, self._cancel, after, before,
                               _worker_class=GeneratorWorker, _ignore_errors=True)
        worker.yielded.connect(self._on_progress)
        worker.returned.connect(self._on_returned)
        worker.errored.connect(self._on_errored)
        worker.finished.connect(self._on_finished)
        self._worker, self._worker_done = worker, False
        self._t0, self._frac, self._eta = time.perf_counter(), 0.0, None
        self._set_running(True)
        self.progress.value = 0
        self._show_time()
        worker.start()

    def cancel(self, *_) -> None:
        """Stop after the frame being computed; finished frames are kept."""
        if self._running and self._worker is not None:
            self._cancel.set()
            self.cancel_button.enabled = False
            self.eta.value = tr("cancelling after the current frame ...")
            self.write_log(tr("Cancel requested: stopping after the current frame."))

    def stopper(self) -> Callable[[], None]:
        """A function that asks a run to stop after its frame (the widget is
        closed); it works while the panel is torn down."""
        return self.shutdown

    def shutdown(self) -> None:
        """The dock or the viewer closes: stop the run after its frame, stop the
        timers and the display, and disconnect the worker, so that nothing calls
        into the closed panel (it works while the panel is torn down)."""
        self._closed = True
        self._cancel.set()
        self._steps = None
        worker = self._worker
        if worker is not None:
            for signal, slot in ((worker.yielded, self._on_progress),
                                 (worker.returned, self._on_returned),
                                 (worker.errored, self._on_errored),
                                 (worker.finished, self._on_finished)):
                try:
                    signal.disconnect(slot)
                except (TypeError, RuntimeError):  # gone already
                    pass
        for timer in (self._clock, self._step_timer):
            try:
                timer.stop()
            except RuntimeError:  # deleted with the panel
                pass
        gc.unfreeze()  # see _frozen_gc

    def _show_time(self) -> None:
        """Frames done, time elapsed and left (also between frames: the clock)."""
        if not self._running or self._cancel.is_set() or self._worker_done:
            return
        frac = self._frac
        elapsed = time.perf_counter() - self._t0
        done = int(round(frac * self._n_deformed))
        parts = [tr("{done}/{total} frames").format(done=done, total=self._n_deformed),
                 tr("{time} elapsed").format(time=format_seconds(elapsed))]
        if 0 < frac < 1 and self._eta is not None:  # the engine's estimate
            left = self._eta[0] - (time.perf_counter() - self._eta[1])  # counts down
            parts.append(tr("about {time} left").format(time=format_seconds(left)))
        if self.preparing and frac == 0:
            parts.append(tr(PREPARING))
        elif is_compiling():  # a frame's time then is mostly compilation
            parts.append(tr(COMPILING))
        self.eta.value = " · ".join(parts)

    def _on_progress(self, event) -> None:
        self._frac = float(min(max(event.fraction, 0.0), 1.0))
        self._eta = None if event.eta_s is None else (event.eta_s, time.perf_counter())
        self.progress.value = int(round(1000 * self._frac))
        self._show_time()
        if event.stage in LOGGED_STAGES:
            self.write_log(str(event))

    def _on_returned(self, outcome) -> None:
        from napari.utils.notifications import show_info

        analysis, prepared = outcome
        done, total = analysis.n_done - 1, len(analysis.frames) - 1
        self.progress.value = int(round(1000 * done / max(1, total)))
        took = format_seconds(analysis.seconds)
        if analysis.cancelled:
            self.write_log(tr("cancelled in {seconds:.1f} s: {done}/{total} frames "
                              "computed").format(
                seconds=analysis.seconds, done=done, total=total))
            final = tr("{done}/{total} frames · cancelled in {time}").format(
                done=done, total=total, time=took)
        else:
            self.write_log(tr("finished in {seconds:.1f} s: {done}/{total} frames "
                              "computed").format(
                seconds=analysis.seconds, done=done, total=total))
            final = tr("{done}/{total} frames · finished in {time}").format(
                done=done, total=total, time=took)
        last = next((r for r in reversed(analysis.results) if r is not None), None)
        if last is not None and done > 0:
            self.write_log(result_summary(last, self._units))
        self.eta.value = tr("{status}; showing the results ...").format(status=final)
        try:
            steps = self.show_results(analysis, prepared) if self.show_results else None
        except Exception as exc:
            self._display_failed(exc)
            return
        if analysis.cancelled:
            show_info(ntr("napari-aldic: cancelled; {done} finished frame kept",
                          "napari-aldic: cancelled; {done} finished frames kept", done).format(
                done=done))
        if getattr(analysis, "error", ""):  # a bad frame stopped the run
            from napari.utils.notifications import show_warning

            self.write_log(tr("stopped early: {error}").format(error=analysis.error))
            show_warning(tr("napari-aldic: stopped early, {done} finished frame(s) kept: "
                            "{error}").format(done=done, error=analysis.error))
        self._steps = iter(steps) if steps is not None else None
        self.display_steps = []
        self._drive(final)

    def _drive(self, final: str) -> None:
        """One step of showing the results; the next one in the next turn of the
        event loop."""
        if self._closed:
            return
        try:
            if self._steps is not None:
                t0, c0 = time.perf_counter(), time.thread_time()
                try:
                    hint = next(self._steps)
                finally:
                    self.display_steps.append((t0, time.perf_counter(),
                                               time.thread_time() - c0))
                # a pause: the event loop (paint, input) runs between two steps, and a
                # layer just made visible is drawn before the next one is added
                self._final = final
                self._step_timer.start(DRAW_PAUSE_MS if hint == "draw" else STEP_PAUSE_MS)
                return
        except StopIteration:
            pass
        except Exception as exc:  # never crash the viewer on a display problem
            self._display_failed(exc)
            return
        self._steps = None
        self.eta.value = final
        self._maybe_done()

    def _display_failed(self, exc: BaseException) -> None:
        from napari.utils.notifications import show_error

        show_error(tr("napari-aldic: could not show the results: {exc}").format(exc=exc))
        self.write_log(tr("ERROR showing results: {exc}").format(exc=exc))
        self.eta.value = tr("finished; the results could not be shown (see log)")
        self._steps = None
        self._maybe_done()

    def _on_errored(self, exc: BaseException) -> None:
        from napari.utils.notifications import show_error

        msg = with_explanation(exc)
        self.write_log(tr("ERROR: {msg}").format(msg=msg))
        self.eta.value = tr("failed (see log)")
        show_error(f"napari-aldic: {msg}")

    def _on_finished(self) -> None:
        self._worker, self._worker_done = None, True
        self._maybe_done()

    def _maybe_done(self) -> None:
        """The run ends when the worker is done and its results are shown."""
        if self._running and self._worker_done and self._steps is None:
            gc.unfreeze()  # see _frozen_gc
            self._set_running(False)


def _frozen_gc(after: Callable[[Analysis], Any]) -> Callable[[Analysis], Any]:
    """``after`` that first freezes Python's garbage collector until the run ends.

    Making and adding the result layers allocates many objects; a full collection
    then would scan the whole napari process (~0.3 s with every thread stopped) in
    the middle of showing the results. Objects that exist already are left out of
    collections until the run ends (:func:`gc.unfreeze`), when they are collected
    as usual again.
    """
    def frozen(analysis: Analysis):
        gc.freeze()
        return after(analysis)
    return frozen
