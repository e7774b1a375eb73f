"""HRDIC in the SEM on the command line (docs/sem.md):

* ``napari-aldic sem-calibrate T0 T1 ... -o distortion.json``: the spatial
  distortion from rigidly translated images of one undeformed area;
* ``napari-aldic sem-drift I0 I1 ... -o drift.json``: the beam drift from a
  time series of images of the undeformed, unmoved area;
* ``napari-aldic run REF DEF ... --distortion F --drift F --scan-lines``: every
  pair measured with those corrections (pairs, stacks and, with the distortion
  alone, tiled pairs).
"""

from __future__ import annotations

from pathlib import Path

from ..engine import DICParams
from ..engine.io import FrameSource, read_image
from ..engine.sem import (
    ScanTiming,
    calibrate_distortion,
    calibrate_drift,
    correct_distortion,
    correlate_sem,
    load_distortion,
    load_drift,
    scan_timing,
)
from ..engine.viz import plot_scan_lines
from ..i18n import tr
from .console import (
    PROG,
    CLIError,
    clear_bar,
    frame_summary,
    kernel_groups,
    precompile,
    progress_bar,
)
from .masks import read_mask
from .settings import settings_from_args

__all__ = ["sem_calibrate_command", "sem_drift_command", "sem_requested", "run_sem",
           "distortion_corrected"]


def _params(args) -> DICParams:
    return settings_from_args(args, args.params).params


def sem_calibrate_command(args) -> None:
    """``napari-aldic sem-calibrate``: fit and write the distortion model."""
    images = [read_image(p) for p in args.images]
    print(tr("{prog} sem-calibrate: {n} images of the undeformed area, polynomial degree "
             "{degree}").format(prog=PROG, n=len(images), degree=args.degree))
    model = calibrate_distortion(images, degree=args.degree, params=_params(args),
                                 names=[Path(p).name for p in args.images],
                                 pixel_size=args.pixel_size, unit=args.unit,
                                 progress=progress_bar("  " + tr("calibration")))
    clear_bar()
    for im in model.images[1:]:
        print("  " + tr("{name}: translation ({tx:+.2f}, {ty:+.2f}) px").format(
            name=im["name"], tx=im["translation_px"][0], ty=im["translation_px"][1]))
    s = model.summary()
    print("  " + tr("distortion up to {corner:.2f} px at the corners; fit residual "
                    "{rms:.4f} px RMS over {n} nodes").format(
                        corner=s["max_corner_px"], rms=model.residual_rms, n=model.n_nodes))
    print(f"  -> {model.save(args.output).resolve()}")


def _timing(args, first: Path) -> ScanTiming:
    if args.dwell is not None and args.line_time is not None:
        return ScanTiming(args.dwell, args.line_time)
    meta = scan_timing(first) if first.suffix.lower() in (".tif", ".tiff") else None
    if meta is None:
        raise CLIError(tr("{name} records no scan timing (FEI or Zeiss metadata): give "
                          "--dwell and --line-time").format(name=first.name))
    return ScanTiming(args.dwell if args.dwell is not None else meta.dwell,
                      args.line_time if args.line_time is not None else meta.line_time)


def sem_drift_command(args) -> None:
    """``napari-aldic sem-drift``: fit and write the drift model."""
    timing = _timing(args, Path(args.images[0]))
    if args.start_times is not None and len(args.start_times) != len(args.images):
        raise CLIError(tr("--start-times gives {n} times for {m} images").format(
            n=len(args.start_times), m=len(args.images)))
    images = [read_image(p) for p in args.images]
    print(tr("{prog} sem-drift: {n} images, dwell {dwell:g} s, line time {line:g} s, "
             "polynomial degree {degree}").format(prog=PROG, n=len(images), dwell=timing.dwell,
                                                  line=timing.line_time, degree=args.degree))
    model = calibrate_drift(images, timing, start_times=args.start_times, degree=args.degree,
                            params=_params(args), names=[Path(p).name for p in args.images],
                            gap=args.gap, progress=progress_bar("  " + tr("calibration")),
                            distortion=None if args.distortion is None
                            else load_distortion(args.distortion))
    clear_bar()
    for im in model.images:
        t = im["start_time_s"]
        dx, dy = model.displacement(t)
        print("  " + tr("{name}: scan start {t:.3f} s, drift ({dx:+.3f}, {dy:+.3f}) px").format(
            name=im["name"], t=t, dx=float(dx), dy=float(dy)))
    print("  " + tr("fit residual {rms:.4f} px RMS").format(rms=model.residual_rms))
    print(f"  -> {model.save(args.output).resolve()}")


# ------------------------------------------------------------------ run
def sem_requested(args) -> bool:
    return bool(getattr(args, "distortion", None) or getattr(args, "scan_lines", False)
                or getattr(args, "drift", None))


def distortion_corrected(args, res):
    """``res`` corrected with ``--distortion`` (unchanged without it)."""
    path = getattr(args, "distortion", None)
    return res if path is None else correct_distortion(res, load_distortion(path))


def _frame_times(args, n: int):
    times = getattr(args, "start_times", None)
    if times is not None and len(times) != n:
        raise CLIError(tr("--start-times gives {n} times for {m} frames").format(
            n=len(times), m=n))
    return times


def run_sem(args, params, units, tiled_run) -> None:
    """``run`` with SEM corrections: every frame against frame 0, one result
    file per frame (a pair: OUT.npz; a stack: OUT/frame_#####.npz), and with
    ``--scan-lines`` the figure of the shifts beside each result."""
    if args.reference != "accumulative":
        raise CLIError(tr("SEM corrections measure every frame against frame 0: "
                          "--reference incremental is not available with them"))
    if not (args.scan_lines or args.drift) and tiled_run():
        return  # a large pair, block by block, corrected for distortion after
    distortion = load_distortion(args.distortion) if args.distortion else None
    drift = load_drift(args.drift) if args.drift else None
    roi = read_mask(args.roi) if args.roi is not None else None
    with FrameSource(args.inputs) as src:
        n = len(src)
        times = _frame_times(args, n)
        out = _outputs(args.output, n)
        print(tr("{prog} run: reference {frame_name}, {n_deformed} deformed frame(s); SEM "
                 "corrections: {what}").format(prog=PROG, frame_name=src.frame_name(0),
                                               n_deformed=n - 1, what=_what(args)))
        precompile(kernel_groups(params.method))  # a first run: in parallel processes
        for k in range(1, n):
            res = correlate_sem(src[0], src[k], roi=roi, params=params, distortion=distortion,
                                scan_lines=args.scan_lines, drift=drift,
                                start_times=None if times is None else (times[0], times[k]),
                                progress=progress_bar("  " + tr("frame {k}/{last}").format(
                                    k=k, last=n - 1)))
            res.meta["inputs"] = {"reference": src.frame_name(0), "deformed": src.frame_name(k),
                                  "frame": k, "roi": None if args.roi is None else str(args.roi)}
            if units is not None:
                res.meta["units"] = units.to_dict()
            _write(res, out(k), src.frame_name(k), k, n - 1)


def _what(args) -> str:
    parts = [tr("distortion ({name})").format(name=Path(args.distortion).name)
             if args.distortion else None,
             tr("drift ({name})").format(name=Path(args.drift).name) if args.drift else None,
             tr("scan lines") if args.scan_lines else None]
    return ", ".join(p for p in parts if p)


def _outputs(output: Path | None, n: int):
    if n == 2:
        path = Path("aldic_result.npz") if output is None else output.expanduser()
        if path.suffix.lower() != ".npz":
            path = path / "frame_00001.npz"
        return lambda k: path
    folder = Path("aldic_result") if output is None else output.expanduser()
    if folder.suffix.lower() == ".npz":
        folder = folder.with_suffix("")
    return lambda k: folder / f"frame_{k:05d}.npz"


def _write(res, path: Path, name: str, k: int, last: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    res.save(path)
    clear_bar()
    print(tr("frame {k}/{last} ({frame_name})").format(k=k, last=last, frame_name=name) + ":")
    for line in frame_summary(res):
        print(f"  {line}")
    print(f"  -> {path.resolve()}")
    sem = res.meta.get("sem", {})
    if "scan_lines" in sem:
        lines = sem["scan_lines"]
        print("  " + tr("scan lines shifted: {n_ref} in the reference, {n_def} in the deformed "
                        "image").format(n_ref=len(lines["reference"]["rows"]),
                                        n_def=len(lines["deformed"]["rows"])))
        png = plot_scan_lines(res, path.with_name(path.stem + "_scanlines.png"),
                              title=f"frame {k}: {name}")
        print(f"  -> {png.resolve()}")
