"""``watch``: live DIC of a folder a camera writes into, frame by frame.

The first frame file (natural order, :mod:`.watch_files`) is frame 0, the
reference; every later file is correlated once it is complete, with exactly
the computation of ``track`` run serially (:class:`~.sequence.SequenceRun`:
the same guess rule, the same composition, the same run folder). So the run
folder equals the one ``napari-aldic run FOLDER -o RUN`` writes for the same
files, and is readable with ``load_run`` at any moment:

* frame 0's result is written before the manifest (``sequence.json``), so a
  reader never finds a manifest without a frame;
* for each new frame the manifest (the identity of the frames so far, as
  ``track`` would record it) and the field store grow first, then the frame
  is correlated and its result file renamed into place;
* a rerun with the same folder and settings resumes: the frames recorded
  are checked (names, sizes, times, content) and kept; a frame that was in
  progress when the watch stopped is computed again, from the same guess as
  without the interruption (the two frames before it, read back).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.files import RunFolderError, clean_temporaries, folder_lock
from ..core.params import DICParams
from ..core.progress import Cancelled
from ..core.results import DICResult, SequenceResult, load_result
from ..io.stack import read_image
from .runfolder import MANIFEST, check_or_create, run_id, write_manifest
from .sequence import Chain, SequenceRun
from .watch_files import FrameFiles

__all__ = ["watch", "WatchReport", "GrowingFrames"]

#: decoded frames a watch keeps besides frame 0 (the newest, for the identity)
_KEPT = 3


class GrowingFrames:
    """The frames of a watched folder taken so far: a frame source for
    :class:`~.sequence.SequenceRun` (``len``, ``shape``, ``src[k]``,
    ``frame_name``) that grows with :meth:`append`; frame 0 and the newest
    decoded frames stay in memory, older ones are read again when asked for."""

    def __init__(self, name: str):
        self.name = name
        self.files: list[Path] = []
        self.frame_shape: tuple | None = None
        self._cache: dict[int, np.ndarray] = {}

    def append(self, path: Path, image: np.ndarray) -> int:
        """Add the next frame (its file and decoded image); returns its number."""
        if self.frame_shape is None:
            self.frame_shape = tuple(image.shape)
        k = len(self.files)
        self.files.append(Path(path))
        self._cache[k] = image
        for old in [j for j in self._cache if 0 < j <= k - _KEPT]:
            del self._cache[old]
        return k

    def __len__(self) -> int:
        return len(self.files)

    @property
    def shape(self) -> tuple:
        return (len(self.files),) + tuple(self.frame_shape[:2])

    def __getitem__(self, k: int) -> np.ndarray:
        k = int(k)
        if k not in self._cache:
            return read_image(self.files[k])
        return self._cache[k]

    def frame_name(self, k: int) -> str:
        return str(self.files[k])


@dataclass
class WatchReport:
    """What a watch did: the run (``sequence``, frames read when used),
    frames computed now and resumed from the folder, why it ended
    (``"idle"``, ``"stopped"``, ``"max_frames"``), files skipped (name,
    reason) and files that came too late (sorting before a frame taken)."""

    sequence: SequenceResult | None
    computed: list = field(default_factory=list)
    resumed: list = field(default_factory=list)
    ended: str = "idle"
    skipped: list = field(default_factory=list)
    late: list = field(default_factory=list)
    folder: Path | None = None


def watch(folder, out_dir, *, pattern: str | None = None, roi=None,
          params: DICParams | None = None, reference: str = "accumulative", refine=None,
          meta: dict | None = None, idle_timeout: float | None = None, poll: float = 0.05,
          settle: float = 0.25, stall: float = 10.0, max_frames: int | None = None,
          on_frame: Callable[[int, DICResult, dict], None] | None = None,
          on_tick: Callable[[], None] | None = None,
          stop: Callable[[], bool] | None = None) -> WatchReport:
    """Correlate the frames of ``folder`` as they arrive, into the run folder ``out_dir``.

    Parameters
    ----------
    folder : path
        The folder the camera writes into.
    out_dir : path
        The run folder (``track``'s format); resumed when it holds this watch.
    pattern : str, optional
        Glob of the frame file names (case-insensitive), default every image file.
    roi, params, reference, refine, meta
        As for :func:`~napari_aldic.engine.track` (``reference`` is
        ``"accumulative"`` or ``"incremental"``).
    idle_timeout : float, optional
        End after this many seconds without a new frame, counted from the
        reference frame on (before it the watch waits for the camera;
        default: never).
    poll, settle, stall : float
        Seconds between looks at the folder; how long a file's size and time
        must stay unchanged (see :mod:`.watch_files`); how long an undecodable
        file may hold later ones back before it is skipped.
    max_frames : int, optional
        End after this many frames (frame 0 included).
    on_frame : callable(frame, result, info), optional
        Called after each frame's result is on disk; ``info`` holds
        ``seconds`` (the correlation), ``latency`` (seconds since the file
        was found complete), ``path`` (the frame file), ``files`` (every frame
        file so far, frame 0 first) and ``resumed``.
    on_tick : callable(), optional
        Called at every look at the folder (e.g. to re-read a load file).
    stop : callable() -> bool, optional
        Polled at every look and inside a correlation; True ends the watch
        (a frame in progress is dropped and computed again on resume).
    """
    if reference not in ("accumulative", "incremental"):
        raise ValueError(f"reference={reference!r} must be 'accumulative' or 'incremental'")
    folder = Path(folder).expanduser()
    if folder.exists() and not folder.is_dir():  # a missing one may be made by the camera
        raise ValueError(f"cannot watch {folder}: it is a file, not a folder")
    out = Path(out_dir).expanduser()
    files = FrameFiles(folder, pattern, settle, stall)
    src = GrowingFrames(str(folder))
    loop = _Loop(files, src, poll, idle_timeout, stop, on_tick)
    recorded = _recorded_frames(out)
    if not loop.wait_for(max(recorded, 1), resuming=recorded > 0):
        return WatchReport(None, ended=loop.ended, skipped=files.skipped, late=files.late)
    run = SequenceRun(src, list(range(max(recorded, 1))), reference, None, roi, None,
                      params or DICParams(), refine, dict(meta or {}),
                      lambda event: None, None)
    report = WatchReport(None, folder=out)
    live = _Live(run, loop, on_frame, report)
    run.on_frame = live.announce
    with folder_lock(_made(out)):
        clean_temporaries(out)
        chain, todo = _open(run, out, recorded)
        report.resumed = [k for k, r in zip(run.idx, run.results) if k and r is not None]
        live.catch_up(todo, chain)
        live.follow(chain, max_frames)
    report.sequence = run.partial(cancelled=loop.ended == "stopped")
    report.ended, report.skipped, report.late = loop.ended, files.skipped, files.late
    return report


def _made(out: Path) -> Path:
    if out.exists() and not out.is_dir():
        raise RunFolderError(f"cannot use {out} as a run folder: it is a file", out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _recorded_frames(out: Path) -> int:
    """How many frames the manifest of ``out`` lists (0: a new run folder)."""
    manifest = out / MANIFEST
    if not manifest.exists():
        return 0
    try:
        info = json.loads(manifest.read_text())
        return len(info.get("frames") or [])
    except (OSError, ValueError, AttributeError) as exc:
        raise RunFolderError(f"cannot read the run manifest {manifest}: {exc}", out) from None


def _open(run: SequenceRun, out: Path, recorded: int) -> tuple[Chain, list[int]]:
    """Start (or check and resume) the run folder ``out``; returns the
    guess chain of the next frame (the last two results, as without an
    interruption) and the indices of recorded frames still to compute."""
    info = run.identity()
    rid = run_id(info)
    if recorded:
        check_or_create(out, json.loads(json.dumps(info)))
        _align_store(out, run.idx, rid)
    else:
        _refuse_foreign(out, rid)
    run.out, run.run_id = out, rid
    ref_img = run.start()
    if not recorded:  # the manifest last: a reader never sees it without frame 0
        write_manifest(out, info)
    _drop_unfinished(run)
    todo = run.load_finished()
    chain = Chain(ref_img=ref_img)
    return chain, todo


def _result(run: SequenceRun, i: int) -> DICResult:
    r = run.results[i]
    return r if isinstance(r, DICResult) else run.load_frame(i)


def _refuse_foreign(out: Path, rid: str) -> None:
    """A new watch needs a folder without results (but frame 0 of this very
    watch, written before a kill left the manifest unwritten)."""
    found = sorted(out.glob("*.npz"))
    for p in found:
        if p.name.startswith("frame_") and p.name != "frame_00000.npz" or \
                p.name == "frame_00000.npz" and load_result(p).meta.get("run_id") != rid:
            raise RunFolderError(f"{out} holds result files ({p.name}) but no {MANIFEST}: "
                                 "results of another analysis. Choose an empty folder", out)


def _align_store(out: Path, idx: list[int], rid: str) -> None:
    """The field store of a watch stopped between growing the manifest and
    the store: grow the store too."""
    from ..io.zarrstore import STORE_NAME, FieldStore, open_fields

    if not (out / STORE_NAME).is_dir():
        return
    attrs = dict(open_fields(out).attrs)
    old = attrs.get("frames") or []
    if old != idx and old == idx[:len(old)]:
        store = FieldStore(out, attrs.get("run_id"), old, attrs["grid_xs"], attrs["grid_ys"])
        store.extend(idx, rid)


def _drop_unfinished(run: SequenceRun) -> None:
    """Remove frame files the store does not record as finished (a watch
    killed between writing a frame and recording it): computed again."""
    trusted = run.store.trusted()
    for i, k in enumerate(run.idx):
        path = run.path_of(k)
        if i and not trusted[i] and path.exists():
            path.unlink()


@dataclass
class _Loop:
    """Looking at the folder: the next complete frame, idle time, stop requests."""

    files: FrameFiles
    src: GrowingFrames
    poll: float
    idle_timeout: float | None
    stop: Callable[[], bool] | None
    on_tick: Callable[[], None] | None
    ended: str = "idle"
    last: float = field(default_factory=time.monotonic)
    found: dict = field(default_factory=dict)  # frame -> monotonic time it was complete

    def stopped(self) -> bool:
        if self.stop is not None and self.stop():
            self.ended = "stopped"
            return True
        return False

    def next(self) -> int | None:
        """Wait for the next frame (appended to ``src``; returns its number),
        or None when stopped or idle for ``idle_timeout``."""
        while not self.stopped():
            if self.on_tick is not None:
                self.on_tick()
            got = self.files.next_frame()
            if got is not None:
                self.last = time.monotonic()
                k = self.src.append(*got)
                self.found[k] = self.last
                return k
            if self.idle_timeout is not None and len(self.src) and \
                    time.monotonic() - self.last > self.idle_timeout:
                self.ended = "idle"
                return None
            time.sleep(self.poll)
        return None

    def wait_for(self, n: int, resuming: bool) -> bool:
        """Take the first ``n`` frames (the reference; on resume, the frames
        recorded). False when stopped or idle first."""
        while len(self.src) < n:
            if self.next() is None:
                if resuming and len(self.src):
                    raise RunFolderError(
                        f"{self.files.folder} holds {len(self.src)} complete frame file(s) "
                        f"but the run folder records {n}: frame files were removed or "
                        "renamed. Watch into an empty folder", None)
                return False
        return True


@dataclass
class _Live:
    """The frames of a running watch: computed as they arrive, announced."""

    run: SequenceRun
    loop: _Loop
    on_frame: Callable | None
    report: WatchReport
    _t0: float = 0.0
    _last: int = 0  # index of the frame the guess chain ends with

    def announce(self, k: int, res: DICResult) -> None:
        """``SequenceRun``'s ``on_frame``: the result is on disk now."""
        now = time.monotonic()
        self.report.computed.append(k)
        if self.on_frame is not None:
            self.on_frame(k, res, {"seconds": now - self._t0, "path": self.run.src.files[k],
                                   "files": list(self.run.src.files),
                                   "latency": now - self.loop.found.get(k, self._t0),
                                   "resumed": False})

    def compute(self, i: int, chain: Chain) -> bool:
        """Frame ``idx[i]``; False when the watch was stopped meanwhile."""
        self._t0 = time.monotonic()
        run = self.run
        if run.reference == "accumulative" and self._last != i - 1:
            # resumed: the guess of a straight run, the two frames before it
            chain.prev = _result(run, i - 1) if i > 1 else None
            chain.before = _result(run, i - 2) if i > 2 else None
        try:
            run.step(i, chain, cancel=self.loop.stopped)
        except Cancelled:
            self.loop.ended = "stopped"
            return False
        self._last = i
        return True

    def catch_up(self, todo: list[int], chain: Chain) -> None:
        """Frames recorded but not finished when the watch stopped."""
        for i in todo:
            if not self.compute(i, chain):
                return

    def follow(self, chain: Chain, max_frames: int | None) -> None:
        """Frames as they arrive: grow the manifest and the store, correlate."""
        run = self.run
        while self.loop.ended != "stopped":
            self.loop.last = max(self.loop.last, time.monotonic())  # idle: while waiting
            if max_frames is not None and len(run.idx) >= max_frames:
                self.loop.ended = "max_frames"
                return
            k = self.loop.next()
            if k is None:
                return
            i = run.extend(k)
            info = run.identity()
            run.run_id = write_manifest(run.out, info)
            run.store.extend(run.idx, run.run_id)
            if not self.compute(i, chain):
                return
