"""``napari-aldic watch``: live DIC of a folder a camera writes into.

Every complete frame file is correlated as it arrives, into a run folder of
``napari-aldic run``'s format (resumed by the same command); one line per
frame; with ``--probes`` (and ``--load``) a probe CSV grows a row per frame.
Ends after ``--idle-timeout`` seconds without a new frame (exit 0), or on
Ctrl+C (exit 130) / SIGTERM (exit 0), the folder consistent either way.
"""

from __future__ import annotations

import signal
from contextlib import contextmanager

import numpy as np

from ..engine import LiveProbes, compute_strain, watch
from ..i18n import tr
from .console import PROG, CLIError, kernel_groups, precompile
from .masks import read_mask
from .probe import probe_set
from .settings import STRAIN_OPTIONS, settings_from_args


def watch_command(args) -> int:
    """``napari-aldic watch``; returns the exit code."""
    settings = settings_from_args(args, args.params)
    if args.output is None:
        raise CLIError(tr("give the run folder: -o RUN_DIR"))
    for name in ("idle_timeout", "poll", "settle", "stall"):
        value = getattr(args, name)
        if value is not None and not value >= 0:
            raise CLIError(tr("--{option} {value} must be a number of seconds >= 0").format(
                option=name.replace("_", "-"), value=value))
    roi = read_mask(args.roi) if args.roi is not None else None
    strain = {STRAIN_OPTIONS[k]: getattr(args, k) for k in STRAIN_OPTIONS
              if getattr(args, k, None) is not None}
    strain = {**(settings.strain or {}), **strain}
    probes = _live_probes(args, settings.units, strain)
    params = settings.params
    print(tr("{prog} watch: {folder} -> {out}; subset {subset} px, step {step} px, method "
             "{method}, reference {reference} (Ctrl+C stops)").format(
                 prog=PROG, folder=args.folder, out=args.output, subset=params.subset,
                 step=params.step, method=params.method, reference=args.reference), flush=True)
    precompile(kernel_groups(params.method, "strain"))  # first run: before the frames arrive
    show = _FrameLines(strain, probes)
    with _stop_signals() as stop:
        if probes is not None:
            probes.start(args.output)
        report = watch(args.folder, args.output, pattern=args.pattern, roi=roi, params=params,
                       reference=args.reference,
                       meta={"units": settings.units.to_dict()} if settings.units else None,
                       idle_timeout=args.idle_timeout, poll=args.poll, settle=args.settle,
                       stall=args.stall, max_frames=args.max_frames, on_frame=show,
                       on_tick=probes.tick if probes is not None else None, stop=stop)
        if probes is not None and report.sequence is not None:
            probes.close(args.output)
    _summary(report, show)
    return 130 if stop.signal == signal.SIGINT else 0


def _live_probes(args, units, strain) -> LiveProbes | None:
    """The live probe CSV of ``--probes``/``--line``/... with ``--probe-csv``."""
    given = args.probes is not None or any(getattr(args, k) for k in
                                           ("line", "point", "area", "circle"))
    if not given:
        if args.probe_csv is not None or args.load is not None:
            raise CLIError(tr("--probe-csv and --load go with probes: --probes FILE.json or "
                              "--line/--point/--area/--circle"))
        return None
    if args.probe_csv is None:
        raise CLIError(tr("probes need --probe-csv OUT.csv (the CSV that grows a row per "
                          "frame)"))
    if args.load is not None and args.area_mm2 is None:
        raise CLIError(tr("--load needs --area-mm2 A (the specimen's cross-section in "
                          "mm²) for the stress"))
    return LiveProbes(probe_set(args), args.probe_csv, load=args.load, area_mm2=args.area_mm2,
                      load_column=args.load_column, sync=args.sync, fps=args.fps,
                      offset=args.offset, units=units, fields=tuple(args.fields or ()),
                      strain=strain or None)


class _FrameLines:
    """One line per frame: number, seconds, trusted fraction, mean strains."""

    def __init__(self, strain: dict, probes: LiveProbes | None):
        self.strain, self.probes, self.latency = strain, probes, []

    def __call__(self, k: int, res, info: dict) -> None:
        self.latency.append(info["latency"])
        if self.probes is not None:
            self.probes.add(k, res)
        s = compute_strain(res, **self.strain)
        ok = s.valid & np.isfinite(s.exx) & np.isfinite(s.eyy)
        exx = float(np.mean(s.exx[ok])) if ok.any() else float("nan")
        eyy = float(np.mean(s.eyy[ok])) if ok.any() else float("nan")
        print(tr("frame {k}: {seconds:.2f} s, trusted {trusted:.1%}, mean exx {exx:+.5f}, "
                 "eyy {eyy:+.5f} ({name})").format(
                     k=k, seconds=info["seconds"], trusted=res.n_valid / max(len(res), 1),
                     exx=exx, eyy=eyy, name=info["path"].name), flush=True)


def _summary(report, show: _FrameLines) -> None:
    for name, why in report.skipped:
        print("  " + tr("skipped {name}: {why}").format(name=name, why=why))
    for name in report.late:
        print("  " + tr("ignored {name}: it sorts before frames already analysed (an "
                        "offline run of the folder would number the frames differently)").format(
                            name=name))
    ended = {"idle": tr("no new frame within the idle timeout"), "stopped": tr("stopped"),
             "max_frames": tr("--max-frames reached")}[report.ended]
    lat = (tr("; latency median {median:.2f} s, max {max:.2f} s").format(
        median=float(np.median(show.latency)), max=float(np.max(show.latency)))
        if show.latency else "")
    print(tr("{n} frame(s) analysed, {m} resumed from the run folder; {ended}").format(
        n=len(report.computed), m=len(report.resumed), ended=ended) + lat, flush=True)


@contextmanager
def _stop_signals():
    """SIGINT and SIGTERM ask the watch to stop (``stop()`` turns True,
    ``stop.signal`` says which); the handlers are restored afterwards."""

    class Stop:
        signal = None

        def __call__(self) -> bool:
            return self.signal is not None

    stop = Stop()

    def handler(signum, frame):
        stop.signal = signum

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for s, h in old.items():
            signal.signal(s, h)
