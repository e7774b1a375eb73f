"""``napari-aldic run``: correlate a pair, a TIFF stack or a folder of images
against frame 0. A pair given ``-o OUT.npz`` writes one result file; a stack
(or any input given ``-o FOLDER``) writes a run folder in ``track``'s format
(``sequence.json``, ``frame_#####.npz``, ``fields.zarr``), which the same command
resumes; ``--scheduler threads|processes|ADDRESS`` runs its frames in parallel
(on a dask cluster at ADDRESS: docs/cluster.md)."""

from __future__ import annotations

import logging
import time
from pathlib import Path

from ..engine import correlate, track
from ..engine.io import FrameSource, write_settings
from ..engine.viz import plot_displacement
from ..i18n import tr
from .console import (
    PROG,
    CLIError,
    clear_bar,
    close_bar,
    frame_summary,
    kernel_groups,
    log_frame,
    precompile,
    progress_display,
)
from .masks import read_mask
from .sem import run_sem, sem_requested
from .settings import settings_from_args
from .tiled import metadata_units, run_tiled_pair, units_line
from .volume import run_volume

log = logging.getLogger("napari_aldic.cli")


def run_command(args) -> None:
    """``napari-aldic run``: every frame against frame 0."""
    try:
        _run(args)
    finally:
        close_bar()


def _run(args) -> None:
    settings = settings_from_args(args, args.params)
    params, units = settings.params, settings.units
    if getattr(args, "volume", False):
        return run_volume(args, params)
    if getattr(args, "block", None):
        raise CLIError(tr("--block reads volumes by blocks: it needs --volume (2-D images "
                          "larger than memory use --tile-size)"))
    if args.params_out is not None:
        used = settings.replace(tracking={"reference": args.reference})
        print(tr("parameters written to {resolve}").format(
                     resolve=write_settings(args.params_out, used).resolve()))
    if sem_requested(args):  # issue 27: SEM corrections, docs/sem.md
        if units is None:  # the pixel size recorded in the images, if any
            units = metadata_units(args.inputs)
        return run_sem(args, params, units,
                       lambda: run_tiled_pair(args, params, units, args.output))
    if run_folder_of(args.output, pair=True) is None and \
            run_tiled_pair(args, params, units, args.output):
        return  # a large pair, read tile by tile and correlated block by block
    roi = read_mask(args.roi) if args.roi is not None else None
    with FrameSource(args.inputs, channel=getattr(args, "channel", None)) as src:
        n = len(src)
        source = {} if units is not None else src.units_source
        if units is None and src.units is not None:  # recorded by the instrument
            units = src.units
            print("  " + units_line(units, source))
        if src.channel is not None:
            print("  " + tr("channel {channel} of {axes} {name}").format(
                channel=src.channel, axes=src.axes, name=src.name))
        folder = run_folder_of(args.output, pair=n == 2 and args.reference == "accumulative")
        print(tr("{prog} run: reference {frame_name}, {n_deformed} deformed frame(s); "
                 "subset {subset} px, step {step} px, method {method}, "
                 "reference {reference}").format(
                     prog=PROG, frame_name=src.frame_name(0), n_deformed=n - 1,
                     subset=params.subset, step=params.step, method=params.method,
                     reference=args.reference))
        precompile(kernel_groups(params.method))
        if folder is None:
            out = Path("aldic_result.npz") if args.output is None else args.output.expanduser()
            res = correlate(src[0], src[1], roi=roi, params=params,
                            progress=progress_display(args.progress, 1,
                                                      "  " + tr("frame 1/1")))
            res.meta["inputs"] = {"reference": src.frame_name(0),
                                  "deformed": src.frame_name(1), "frame": 1,
                                  "roi": None if args.roi is None else str(args.roi)}
            if units is not None:  # carried with the result into every export
                res.meta["units"] = units.to_dict()
            if source:
                res.meta["units_source"] = source
            _report(res, _save(res, out), tr("frame 1/1 ({frame_name})").format(
                                                 frame_name=src.frame_name(1)),
                    src if args.plot else None)
            return
        _run_folder(src, folder, roi, params, units, source, args)


def _run_folder(src, folder: Path, roi, params, units, source: dict, args) -> None:
    """Track the stack into the run folder ``folder`` (resuming it)."""
    n = len(src)
    print("  " + tr("run folder {resolve} (rerun the same command to resume)").format(
                        resolve=folder.resolve()))
    loaded: list[int] = []
    bar = progress_display(args.progress, n - 1, " ")

    def progress(event) -> None:
        if event.stage == "frame_loaded":
            loaded.append(event.frame)
        if bar is not None:
            bar(event)

    def show(k: int, res) -> None:
        path = folder / f"frame_{k:05d}.npz"
        _report(res, path, tr("frame {k}/{last} ({frame_name})").format(
                                  k=k, last=n - 1, frame_name=src.frame_name(k)),
                src if args.plot else None)

    t0 = time.perf_counter()
    meta = {"units": units.to_dict()} if units is not None else {}
    if source:  # where the pixel size / frame interval came from
        meta["units_source"] = source
    track(src, roi=roi, params=params, reference=args.reference, out_dir=folder,
          meta=meta or None, progress=progress, on_frame=show, scheduler=_scheduler(args),
          workers=getattr(args, "workers", None))
    close_bar()
    done = n - 1 - len(loaded)
    print(tr("{done} frames in {seconds:.2f} s").format(done=done, seconds=time.perf_counter() - t0)
          + (tr("; {n_loaded} finished frame(s) resumed from {folder}").format(
                    n_loaded=len(loaded), folder=folder) if loaded else ""))


def _scheduler(args):
    """``--scheduler``: None (frames in turn), "threads", "processes" or a
    dask scheduler address; ``--workers`` must be positive."""
    sched, n = getattr(args, "scheduler", None), getattr(args, "workers", None)
    if n is not None and n < 1:
        raise CLIError(tr("--workers {n} must be at least 1").format(n=n))
    if sched is None or sched in ("threads", "processes"):
        return sched
    if "://" not in sched and ":" not in sched:
        raise CLIError(tr("--scheduler {sched!r} is not 'threads', 'processes' or a dask "
                          "scheduler address such as tcp://host:8786").format(
                              sched=sched))
    return sched


def run_folder_of(output: Path | None, pair: bool) -> Path | None:
    """The run folder of ``-o`` (``None``: a pair written to one ``.npz``):
    ``FOLDER`` as given, ``OUT.npz`` of a stack becomes the folder ``OUT``,
    no ``-o`` the folder ``./aldic_result`` (``./aldic_result.npz`` for a pair)."""
    if output is None:
        return None if pair else Path("aldic_result")
    out = output.expanduser()
    if out.suffix.lower() == ".npz":
        return None if pair else out.with_suffix("")
    if out.exists() and not out.is_dir():
        raise CLIError(tr("output {out} exists and is not a folder; give OUT.npz or a "
                          "folder").format(out=out))
    return out


def _save(res, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    return res.save(path)


def _report(res, path: Path, title: str, plot_src=None) -> None:
    """Print one saved result's summary and (given the frames) write its figure."""
    clear_bar()
    print(f"{title}:")
    for line in frame_summary(res):
        print(f"  {line}")
    print(f"  -> {path.resolve()}")
    k = res.meta.get("inputs", {}).get("frame", res.meta.get("frame", 1))
    log_frame(log, res, str(k), path.resolve())
    if plot_src is not None:
        k = res.meta["inputs"]["frame"]
        png = plot_displacement(res, path.with_suffix(".png"), image=plot_src[0],
                                title=f"frame {k}: {plot_src.frame_name(k)}")
        print(f"  -> {png.resolve()}")
