"""``napari-aldic export``: results to MAT, CSV, VTU, DaVis text, PNG, GIF,
MP4 and PDF, each format written on its own (one failing does not stop the rest)."""

from __future__ import annotations

import sys
from pathlib import Path

from ..engine import EncoderNotFoundError, Units, export_result
from ..engine.io import collect_frames
from ..i18n import tr
from .console import PROG, CLIError
from .parser import EXPORT_FORMATS
from .settings import UNIT_OPTIONS, settings_file, settings_from_args, units_from_args

#: file name ending of each format
SUFFIX = {"mat": ".mat", "csv": ".csv", "vtu": ".vtu", "davis": ".txt", "png": ".png",
          "gif": ".gif", "mp4": ".mp4", "pdf": ".pdf"}
IMAGE_FORMATS = ("png", "gif", "mp4")


def export_command(args) -> int:
    """``napari-aldic export``: every requested format; returns the exit code."""
    formats = _formats(args.formats)
    data = _input(args.inputs)
    settings = settings_from_args(args, args.settings)
    strain = False if args.no_strain else (settings.strain or True)
    # read the results (and compute strain) once for every format
    frames, _, _ = collect_frames(data, strain=strain)
    units = _units(args, Units.from_meta(frames[0].result.meta))
    base = _export_base(list(args.inputs), args.output)
    single = len(formats) == 1 and base.suffix.lower() in SUFFIX.values()
    if base.suffix.lower() in SUFFIX.values() and not single:
        base = base.with_suffix("")
    print(tr("{prog} export: {n_frames} frame(s) ({index} to {index2}); "
             "{describe}").format(
                 prog=PROG, n_frames=len(frames), index=frames[0].index, index2=frames[-1].index,
                 describe=units.describe()))
    failed = 0
    for fmt in formats:
        for target, opts in _jobs(fmt, base, single, args):
            if fmt != "davis":
                opts.update(units=units, strain=strain)
            error = _write(frames, target, fmt, opts)
            failed += error is not None
            if isinstance(error, EncoderNotFoundError):
                break  # no encoder for any field of this format: said once
    return 2 if failed else 0


def _units(args, stored: Units | None) -> Units:
    """The units of the export: those stored in the result, with the units of
    ``--settings`` and the unit options applied over them; a warning line says
    when they replace what the result says."""
    file_units = settings_file(args.settings).units
    units = units_from_args(args, file_units if file_units is not None else stored) or Units()
    if stored is None:
        return units
    changed = [k for k in ("pixel_size", "unit") if getattr(units, k) != getattr(stored, k)]
    if stored.has_time:  # a frame interval added to a result without one replaces nothing
        changed += [k for k in ("frame_interval", "time_unit")
                    if getattr(units, k) != getattr(stored, k)]
    if changed:
        given = [f"--{k.replace('_', '-')}" for k in UNIT_OPTIONS
                 if getattr(args, k, None) is not None]
        by = ", ".join(given + (["--settings"] if file_units is not None else []))
        print(tr("{prog}: warning: {by} override the units stored in the result "
                 "({describe}); exporting with {describe2}").format(
                     prog=PROG, by=by, describe=stored.describe(), describe2=units.describe()),
              file=sys.stderr, flush=True)
    return units


def _formats(items: list[str]) -> list[str]:
    """The formats of ``--to`` (comma or space separated), checked."""
    formats = [f.strip().lower() for item in items for f in item.split(",") if f.strip()]
    if not formats:  # --to "" would write nothing and report success
        raise CLIError(tr("no export format given; choose one or more of {join}").format(
            join=", ".join(EXPORT_FORMATS)))
    bad = [f for f in formats if f not in EXPORT_FORMATS]
    if bad:
        raise CLIError(tr("unknown export format(s) {bad}; choose from {join}").format(
                              bad=bad, join=', '.join(EXPORT_FORMATS)))
    return formats


def _input(inputs: list[Path]):
    """One result file or run folder, or a list of result files."""
    for p in inputs:
        if not p.expanduser().exists():
            raise CLIError(tr("no such file or folder: {p}").format(p=p))
    if len(inputs) == 1:
        return inputs[0].expanduser()
    if any(p.is_dir() for p in inputs):
        raise CLIError(tr("give one run folder, or one or more result files"))
    return [p.expanduser() for p in inputs]


def _export_base(inputs: list[Path], output: Path | None) -> Path:
    """Output name without format suffix (see the ``-o`` help)."""
    if output is not None:
        out = output.expanduser()
        return out / "export" if out.is_dir() else out
    first = inputs[0].expanduser()
    if len(inputs) == 1 and first.is_dir():
        return first / "export"
    if len(inputs) == 1:
        return first.with_suffix("")
    return first.parent / "export"


def _jobs(fmt: str, base: Path, single: bool, args) -> list[tuple[Path, dict]]:
    """(target, export_result options) of every file of one format: one per
    field for the image formats, else one."""
    if fmt in IMAGE_FORMATS:
        fields = args.field or ["u"]
        jobs = []
        for field in fields:
            target = base if single and len(fields) == 1 else \
                base.with_name(f"{base.name}_{field}{SUFFIX[fmt]}")
            opts = {"field": field, "frames": args.frames}
            opts.update({"dpi": args.dpi} if fmt == "png" else {"fps": args.fps})
            jobs.append((target, opts))
        return jobs
    opts = {"frames": args.frames}
    if fmt == "pdf" and args.line is not None:
        opts["line"] = tuple(args.line)
    if fmt == "vtu":
        opts["encoding"] = args.encoding
    return [(base if single else base.with_name(base.name + SUFFIX[fmt]), opts)]


def _write(frames, target: Path, fmt: str, opts: dict):
    """Export one file (or one file series); print what was written or the
    error. Returns the error (None when written)."""
    try:
        out = export_result(frames, target, to=fmt, **opts)
    except (EncoderNotFoundError, ValueError, OSError) as exc:
        print(tr("{prog}: error: {fmt}: {join}").format(
                     prog=PROG, fmt=fmt, join=' '.join(str(exc).split())), file=sys.stderr)
        return exc
    paths = out if isinstance(out, list) else [out]
    shown = paths if len(paths) <= 3 else [paths[0], tr("... ({n_paths} files)").format(
                                                            n_paths=len(paths)), paths[-1]]
    for p in shown:
        print(f"  {fmt}: {p.resolve() if isinstance(p, Path) else p}")
    return None
