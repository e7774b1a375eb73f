"""``napari-aldic probe``: line gauges, points and areas over the frames of a run,
optionally with the testing machine's load (stress), to one CSV row per frame."""

from __future__ import annotations

from pathlib import Path

from ..engine.io import read_json_file
from ..engine.probes import (
    AreaProbe,
    LineProbe,
    PointProbe,
    ProbeSet,
    attach_load,
    export_kymograph_csv,
    export_probe_plot,
    export_probes_csv,
    kymograph,
    measure_probes,
    read_load_csv,
)
from ..i18n import tr
from .console import PROG, CLIError
from .settings import STRAIN_OPTIONS, units_from_args


def probe_command(args) -> int:
    """``napari-aldic probe``: measure, write the CSV (and plots); returns 0."""
    run = args.run.expanduser()
    if not run.exists():
        raise CLIError(tr("no run folder or result file at {run}").format(run=run))
    probes = probe_set(args)
    if args.load is None and (args.area_mm2 is not None or args.sync or args.fps):
        raise CLIError(tr("--area-mm2, --sync and --fps go with --load LOAD.csv"))
    if args.load is not None and args.area_mm2 is None:
        raise CLIError(tr("--load needs --area-mm2 A (the specimen's cross-section in "
                          "mm²) for the stress"))
    units = units_from_args(args, None)
    strain = {STRAIN_OPTIONS[k]: getattr(args, k) for k in STRAIN_OPTIONS
              if getattr(args, k, None) is not None} or None
    fields = args.fields or None
    kw = {"fields": fields} if fields else {}
    table = measure_probes(run, probes, strain=strain, units=units, **kw)
    if args.load is not None:
        record = read_load_csv(args.load, load_column=args.load_column)
        attach_load(table, record, area_mm2=args.area_mm2, sync=args.sync, fps=args.fps,
                    offset=args.offset)
        print("  " + tr("load: {describe}; synchronised by {sync}").format(
                            describe=record.describe(), sync=table.info['load']['sync']))
    out = export_probes_csv(table, args.output)
    print(tr("{prog} probe: {n_table} frame(s) ({first} to {last}), {n_probes} "
             "probe(s); lengths in {unit}").format(
                 prog=PROG, n_table=len(table), first=table.frames[0], last=table.frames[-1],
                 n_probes=len(probes), unit=table.units.unit))
    for line in table.status_summary():
        print(f"  {line}")
    print("  " + tr("csv: {resolve}").format(resolve=out.resolve()))
    print("  " + tr("units and probes: {resolve}").format(
                        resolve=out.with_suffix('.json').resolve()))
    if args.plot:
        for fmt in args.plot:
            p = export_probe_plot(table, out.with_suffix(f".{fmt}"))
            print(f"  {fmt}: {p.resolve()}")
    if args.kymograph:
        for i, line in enumerate(probes.lines, 1):
            for name in args.kymograph:
                k = kymograph(run, line, name, units=units, strain=strain)
                p = export_kymograph_csv(k, out.with_name(f"{out.stem}_line{i}_{name}.csv"))
                print("  " + tr("profile of {name} along line{i}, every frame: {resolve}").format(
                                    name=name, i=i, resolve=p.resolve()))
    return 0


def probe_set(args) -> ProbeSet:
    """The probes of the command line (and of ``--probes FILE.json``)."""
    probes = ProbeSet()
    if args.probes is not None:
        try:
            data = read_json_file(Path(args.probes).expanduser(), "probe file")
        except (OSError, ValueError) as exc:
            raise CLIError(tr("cannot read the probe file {probes}: {exc}").format(
                                  probes=args.probes, exc=exc)) from None
        if isinstance(data, dict) and data.get("format") == "napari-aldic-settings":
            if not isinstance(data.get("probes"), dict):  # a parameter file without probes
                raise CLIError(tr("{probes} is a parameter file without a 'probes' section").format(
                                      probes=args.probes))
            data = data["probes"]
        try:
            probes = ProbeSet.from_dict(data.get("probes", data) if isinstance(data, dict)
                                        and "format" not in data else data)
        except ValueError as exc:
            raise CLIError(f"{args.probes}: {exc}") from None
    try:
        probes.lines += [LineProbe(*v) for v in args.line or []]
        probes.points += [PointProbe(*v) for v in args.point or []]
        probes.areas += [AreaProbe.rectangle(*v) for v in args.area or []]
        probes.areas += [AreaProbe.circle(*v) for v in args.circle or []]
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    if not len(probes):
        raise CLIError(tr("give at least one probe: --line X0 Y0 X1 Y1, --point X Y, "
                          "--area X0 Y0 X1 Y1, --circle CX CY R or --probes FILE.json"))
    return probes
