"""Compile the engine's Numba kernels ahead of a first analysis, in parallel
processes (issue 25: the first run).

A fresh environment compiles every kernel on its first call, one after the
other: Numba holds one global compiler lock per process, so threads do not
help. Processes do: each compiles a share of the kernels listed in
``kernels.signatures`` and writes them to Numba's disk cache (every kernel is
``cache=True``), and this process, which compiles its own share meanwhile,
then loads the others from that cache at their first call, in milliseconds.
On Linux, called from a process's only thread (the CLI), the workers are
forked copies of this process, which compile at once; elsewhere (napari,
Jupyter, a thread) fresh interpreters, which first import for ~1.5 s CPU.

:func:`precompile_kernels` returns at once when everything is cached already
(it reads the cache index files only), so the CLI, the widget and the demo
call it before every analysis.
"""

from __future__ import annotations

import atexit
import importlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from ..kernels import signatures as sigs

__all__ = ["precompile_kernels", "kernels_to_compile", "PrecompileReport"]

#: seconds a worker process needs to start before it compiles anything (~1 s
#: CPU: numpy, numba and the kernel modules): its share is that much smaller
_START_COST = 1.5
#: ... and a forked one (a copy of this process, everything imported already)
_FORK_START_COST = 0.1
_ENV = "NAPARI_ALDIC_PRECOMPILE_WORKERS"
_FORK_ENV = "NAPARI_ALDIC_PRECOMPILE_FORK"


@dataclass
class PrecompileReport:
    """What :func:`precompile_kernels` did."""

    #: kernels (``"module.function"``) compiled now, in this process or another
    compiled: list[str] = field(default_factory=list)
    #: processes that compiled (this one included); 0: nothing was to compile
    processes: int = 0
    #: how the worker processes started: "fork" (copies of this process),
    #: "spawn" (fresh interpreters) or "" (none)
    start: str = ""
    #: wall-clock seconds
    seconds: float = 0.0
    #: CPU seconds of each process that compiled, this one first (its
    #: compiling thread; a worker: all of it, start-up included)
    cpu_seconds: list[float] = field(default_factory=list)
    #: ``"kernel: error"`` of kernels that failed to compile ahead (they
    #: compile at their first call instead, as without precompiling)
    errors: list[str] = field(default_factory=list)


def _dispatcher(name: str):
    module, func = name.split(".")
    return getattr(importlib.import_module(f"{__package__.rsplit('.', 1)[0]}.kernels.{module}"),
                   func)


def _is_cached(disp, argtypes: tuple) -> bool:
    """Whether Numba's disk cache holds ``disp`` for ``argtypes`` (index only;
    Numba's own cache key, so a True here is a cache hit at the call)."""
    if tuple(argtypes) in disp.overloads:
        return True
    try:
        cache = disp._cache
        key = cache._index_key(argtypes, disp.targetctx.codegen())
        return key in cache._cache_file._load_index()
    except Exception:  # noqa: BLE001 - another Numba version: assume not cached
        return False


def kernels_to_compile(groups=("local", "aldic")) -> list[str]:
    """The kernels of ``groups`` (see ``kernels.signatures.GROUPS``) that
    neither this process nor the disk cache holds for some listed signature."""
    todo = []
    for name, spelled in sigs.entries(groups):
        disp = _dispatcher(name)
        if not all(_is_cached(disp, sigs.parse(s)) for s in spelled):
            todo.append(name)
    return todo


def _compile(names: list[str]) -> list[tuple[str, str]]:
    """Compile every listed signature of ``names``; ``(name, error)`` of failures."""
    failed = []
    for name in names:
        try:
            disp = _dispatcher(name)
            for s in sigs.KERNELS[name]:
                disp.compile(sigs.parse(s))
        except Exception as exc:  # noqa: BLE001 - reported; compiled at the call instead
            failed.append((name, f"{type(exc).__name__}: {exc}"[:300]))
    return failed


def _spawn(names: list[str]) -> subprocess.Popen:
    """A fresh interpreter compiling ``names`` (a new process rather than a
    ``multiprocessing`` one: nothing of this process is re-imported or forked,
    so it works from a script without a main guard, Jupyter and a Qt GUI).

    It imports the kernel modules only (numpy and numba): the package's and
    the engine's ``__init__`` (SciPy, the readers, ...; ~2 s) are replaced by
    empty packages with the same paths, so the kernels' cache files and keys
    are the ones this process reads."""
    here = Path(__file__).resolve()
    top, engine = __name__.split(".")[:2]
    stubs = [(top, str(here.parents[2])), (f"{top}.{engine}", str(here.parents[1]))]
    code = ("import sys, types\n"
            f"for name, path in {stubs!r}:\n"
            "    sys.modules.setdefault(name, types.ModuleType(name)).__path__ = [path]\n"
            f"from {__name__} import _worker_main\n_worker_main()\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    err = tempfile.TemporaryFile(mode="w+")  # Numba's warnings: a full pipe would stall it
    proc = subprocess.Popen([sys.executable, "-c", code, *names], env=env,
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=err,
                            text=True)
    proc.err_file = err
    return proc


class _Forked:
    """A forked copy of this process compiling ``names`` (Linux, from a process
    running one thread): it starts at once, with every module already imported,
    where a fresh interpreter needs ~1.5 s CPU before it compiles anything. The
    same interface as the ``Popen`` of :func:`_spawn` for :func:`_collect`."""

    def __init__(self, names: list[str]):
        self.err_file = tempfile.TemporaryFile(mode="w+")
        self.returncode = None
        r, w = os.pipe()
        from numba.core.compiler_lock import global_compiler_lock

        # held across the fork, so no other thread holds it in the child's copy
        with global_compiler_lock, warnings.catch_warnings():
            # Python >= 3.12 warns of native threads (OpenBLAS's idle pool, which
            # re-forms in the child): the child only compiles, then leaves
            warnings.simplefilter("ignore", DeprecationWarning)
            self.pid = os.fork()
        if self.pid == 0:  # the child: never returns into the caller's code
            code = 1
            try:
                os.close(r)
                os.dup2(self.err_file.fileno(), 2)
                msg = _work(names).encode()
                while msg:
                    msg = msg[os.write(w, msg):]
                code = 0
            finally:
                os._exit(code)  # not the parent's exit handlers, buffers or finalizers
        os.close(w)
        self._r = r

    def kill(self) -> None:
        """Stop the worker now (it was not collected) and reap it."""
        try:
            os.kill(self.pid, signal.SIGKILL)
            os.waitpid(self.pid, 0)
        except (ProcessLookupError, ChildProcessError):  # gone already
            pass
        os.close(self._r)
        self.err_file.close()

    def communicate(self) -> tuple[str, None]:
        with os.fdopen(self._r, "rb") as pipe:
            out = pipe.read().decode("utf-8", "replace")
        _, status = os.waitpid(self.pid, 0)
        self.returncode = os.waitstatus_to_exitcode(status)
        return out, None


def _add_one(x):
    return x + 1


def _warm_compiler() -> None:
    """Initialise Numba's compiler in this process (its typing and target
    contexts: ~0.4 s CPU, paid by the first compilation or cache load of a
    process) before forking workers, which inherit it instead of each paying
    it again; this process needs it to load their kernels anyway."""
    import numba

    numba.njit(cache=False)(_add_one)(1)


def _can_fork() -> bool:
    """Whether workers may be forked: Linux, this process's only Python thread
    (a GUI, Jupyter or a thread pool would leave locks held in the child)."""
    return (sys.platform.startswith("linux") and hasattr(os, "fork")
            and threading.current_thread() is threading.main_thread()
            and threading.active_count() == 1)


def _fork_wanted(fork: bool | None) -> bool:
    if fork is None:
        fork = os.environ.get(_FORK_ENV, "").strip() != "0"
    return bool(fork) and _can_fork()


def _collect(proc, names: list[str]) -> tuple[list, float]:
    """The failures and the CPU seconds a worker reported (NaN if it died)."""
    out, _ = proc.communicate()
    with proc.err_file as err:
        try:
            got = json.loads(out.strip().splitlines()[-1])
            return [tuple(x) for x in got["failed"]], float(got["cpu_s"])
        except (ValueError, IndexError, KeyError, TypeError):  # died: compiled at the call
            err.seek(0)
            why = f"worker exit {proc.returncode}: {err.read().strip()[-300:]}"
            return [(k, why) for k in names], float("nan")


def _work(names: list[str]) -> str:
    """A worker's job, forked or spawned: compile ``names``; the failures and
    the process's CPU seconds as the JSON line :func:`_collect` reads."""
    failed = _compile(names)
    return json.dumps({"failed": failed, "cpu_s": time.process_time()})


def _worker_main() -> None:
    """Entry of a spawned worker: :func:`_work` on the kernels in ``sys.argv``."""
    print(_work(sys.argv[1:]), flush=True)


def _usable_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def _units(names: list[str]) -> list[tuple[list[str], float]]:
    """``names`` as units that one process compiles, with their seconds: a
    kernel of ``sigs.AFTER`` joins the kernel whose helpers it shares, after
    it, when both are to compile."""
    units = {n: ([n], sigs.COST.get(n, 1.0)) for n in names
             if sigs.AFTER.get(n, ("",))[0] not in names}
    for name in names:
        if name not in units:
            base, secs = sigs.AFTER[name]
            units[base][0].append(name)
            units[base] = (units[base][0], units[base][1] + secs)
    return list(units.values())


def _shares(names: list[str], n: int, start_cost: float = _START_COST) -> list[list[str]]:
    """``names`` split into ``n`` shares of similar compile time (the longest
    unit (:func:`_units`) first, each to the least loaded share); share 0 is
    this process's, the others start late by a worker's start-up
    (``start_cost`` seconds)."""
    load = [0.0] + [start_cost] * (n - 1)
    out: list[list[str]] = [[] for _ in range(n)]
    for unit, secs in sorted(_units(names), key=lambda u: -u[1]):
        i = min(range(n), key=load.__getitem__)
        out[i] += unit
        load[i] += secs
    return [s for s in out if s]  # share 0 holds the costliest unit


def _worker_count(workers: int | None, todo: list[str], start_cost: float) -> int:
    if workers is None:
        env = os.environ.get(_ENV, "").strip()
        workers = int(env) if env.isdigit() else _usable_cpus()
        if sum(sigs.COST.get(k, 1.0) for k in todo) < 2 * max(start_cost, 0.5):
            workers = 1  # a few small kernels: not worth starting a process
    if getattr(sys, "frozen", False):
        workers = 1  # a frozen app's executable is not a Python interpreter
    return max(1, min(workers, len(todo)))


@dataclass
class _Running:
    """A background run of :func:`precompile_kernels` not collected yet."""

    names: list[str]
    procs: list  # (process, its share)
    t0: float


#: background runs in flight (``precompile_kernels(background=True)``): the
#: next foreground call collects them
_RUNNING: list[_Running] = []


def precompile_kernels(groups=("local", "aldic"), workers: int | None = None,
                       on_start=None, fork: bool | None = None,
                       background: bool = False) -> PrecompileReport:
    """Compile the kernels that ``groups`` of analyses need and the cache
    lacks, in up to ``workers`` processes (default: the usable CPUs, or
    ``$NAPARI_ALDIC_PRECOMPILE_WORKERS``; 1 = in this process only).

    ``groups``: ``"local"`` (every 2-D analysis), ``"aldic"`` (AL-DIC's
    global steps), ``"strain"`` (the strain's plane fit), ``"synthetic"`` (the
    synthetic speckle images), or kernels by name (``"lattice.plane_fit"``).
    ``on_start(n_kernels, n_processes)`` is called before compiling starts
    (not when everything is cached). Returns at once (a
    :class:`PrecompileReport` with ``processes == 0``) when nothing is to
    compile, or under ``NUMBA_DISABLE_JIT``. Kernels that fail to compile
    here are reported and compile at their first call, as without this.

    ``fork``: start the workers as forked copies of this process (no interpreter
    start-up; the CLI's case) rather than fresh interpreters; ``None`` forks
    where that is safe (Linux, called from the only Python thread: not from a
    GUI, Jupyter or a thread) unless ``$NAPARI_ALDIC_PRECOMPILE_FORK`` is 0.

    ``background``: start the worker processes and return at once (the report
    lists what they compile, ``seconds`` 0): this process goes on importing and
    reading its inputs meanwhile (the command line, issue 25). The next call
    without ``background`` collects them (its report counts them, its
    ``seconds`` from their start); at exit, workers never collected are stopped.
    """
    from numba.core import config

    t0 = time.perf_counter()
    if config.DISABLE_JIT:
        return PrecompileReport()
    running = _take_running()
    flight = running.names if running is not None else []
    todo = [k for k in kernels_to_compile(groups) if k not in flight]
    fork = _fork_wanted(fork)
    start = _FORK_START_COST if fork else _START_COST
    if background:
        if running is not None:
            _RUNNING.append(running)
        return _start_background(todo, _worker_count(workers, todo, start), fork, t0)
    if running is None and not todo:
        return PrecompileReport(seconds=time.perf_counter() - t0)
    shares = _shares(todo, _worker_count(workers, todo, start), start) if todo else []
    procs = list(running.procs) if running is not None else []
    if on_start is not None:
        on_start(len(flight) + len(todo), len(procs) + len(shares))
    own = list(shares[0]) if shares else []
    if fork and len(shares) > 1:
        _warm_compiler()
    for share in shares[1:]:
        try:
            procs.append((_Forked(share) if fork else _spawn(share), share))
        except OSError:  # no process to start: this process compiles it
            own += share
    c0 = time.thread_time()
    failed = _compile(own)
    cpu = [time.thread_time() - c0] if own else []
    for proc, share in procs:
        more, secs = _collect(proc, share)
        failed += more
        cpu.append(secs)
    return PrecompileReport(compiled=flight + todo, processes=len(cpu),
                            start=("fork" if fork else "spawn") if procs else "",
                            seconds=time.perf_counter() - (t0 if running is None else running.t0),
                            cpu_seconds=cpu, errors=[f"{k}: {e}" for k, e in failed])


def _take_running() -> _Running | None:
    """Every background run in flight, as one (its kernels, its workers, the
    earliest start), removed from :data:`_RUNNING`; None when there is none."""
    if not _RUNNING:
        return None
    runs = _RUNNING[:]
    _RUNNING.clear()
    return _Running([k for r in runs for k in r.names], [p for r in runs for p in r.procs],
                    min(r.t0 for r in runs))


def _start_background(todo: list[str], n: int, fork: bool, t0: float) -> PrecompileReport:
    """Start ``n`` worker processes on ``todo`` (none in this process) and
    leave them in :data:`_RUNNING`."""
    if not todo:
        return PrecompileReport(seconds=time.perf_counter() - t0)
    procs = []
    if fork:
        _warm_compiler()
    for share in _shares(todo, n, 0.0):  # every share is a worker's: equal starts
        try:
            procs.append((_Forked(share) if fork else _spawn(share), share))
        except OSError:  # no process: the foreground call compiles these
            todo = [k for k in todo if k not in share]
    if not procs:
        return PrecompileReport(seconds=time.perf_counter() - t0)
    _RUNNING.append(_Running(todo, procs, t0))
    return PrecompileReport(compiled=todo, processes=len(procs),
                            start="fork" if fork else "spawn")


def _stop_running() -> None:
    """At exit: stop the background workers nobody collected (a command that
    ended before its analysis: an error, ``--help``); Numba writes a cache
    file whole or not at all, so a stopped worker leaves no damaged entry."""
    while _RUNNING:
        for proc, _ in _RUNNING.pop().procs:
            proc.kill()
            if isinstance(proc, subprocess.Popen):
                proc.wait()


atexit.register(_stop_running)
