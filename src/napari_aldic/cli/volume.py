"""``napari-aldic run --volume``: digital volume correlation of 3-D TIFFs.

A pair writes one ``.npz`` (:class:`~napari_aldic.engine.VolumeResult`); a
sequence (a 4-D TIFF, a folder, or more than two files) writes
``frame_#####.npz`` into a folder, every volume against volume 0
(accumulative) or against the previous one with the displacements summed
at the nodes (incremental); frames already in the folder are kept, so the
same command resumes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..engine import (
    compute_strain_volume,
    correlate_volume,
    export_volume,
    load_result,
    track_volumes,
)
from ..engine.io import natural_key, open_volume, read_volumes
from ..i18n import tr
from .console import PROG, CLIError

_EXPORTS = (".mat", ".vtu", ".csv")  # -o of a pair: also written, with the strain


def _params(args, params):
    """Volume defaults where the command line gave none (the API's: 21, 8)."""
    changes = {}
    if getattr(args, "subset", None) is None:
        changes["subset"] = 21
    if getattr(args, "step", None) is None:
        changes["step"] = 8
    return params.replace(**changes) if changes else params


def _roi(args):
    if args.roi is None:
        return None
    try:
        if args.block:
            return open_volume(args.roi)  # read by windows too, nonzero = material
        (m,) = read_volumes([args.roi])
    except (ValueError, FileNotFoundError) as exc:
        raise CLIError(str(exc)) from None
    return np.asarray(m) != 0


def _is_zarr(p: Path) -> bool:
    return p.is_dir() and any((p / n).exists() for n in (".zarray", "zarr.json"))


def _lazy_volumes(inputs) -> list:
    """``--block``: every input opened without reading it (a folder of files
    is a sequence, one volume a file; a zarr folder is one volume)."""
    out = []
    for p in map(Path, inputs):
        if p.is_dir() and not _is_zarr(p):
            files = sorted((f for f in p.iterdir() if f.suffix.lower() in (".tif", ".tiff",
                                                                           ".npy")
                            or _is_zarr(f)), key=lambda f: natural_key(f.name))
            out.extend(open_volume(f) for f in files)
        else:
            out.append(open_volume(p))
    return out


def _volumes(args, step: int) -> list:
    try:
        if args.block:
            if args.block < step:
                raise ValueError(tr("--block {n} is smaller than the node spacing; give at "
                                    "least {step} voxels").format(n=args.block, step=step))
            return _lazy_volumes(args.inputs)
        return read_volumes(args.inputs)
    except (ValueError, FileNotFoundError) as exc:
        raise CLIError(str(exc)) from None


def run_volume(args, params) -> None:
    """Correlate the volumes of ``args.inputs`` (see the module docstring)."""
    params = _params(args, params)
    vols = _volumes(args, params.step)
    if len(vols) < 2:
        raise CLIError(tr("--volume needs a reference and at least one deformed volume; "
                          "{n} given").format(n=len(vols)))
    roi = _roi(args)
    print(tr("{prog} run --volume: {n_deformed} deformed volume(s) of {shape} voxels "
             "(z, y, x); subset {subset}, step {step}, method {method}").format(
                 prog=PROG, n_deformed=len(vols) - 1, shape=" x ".join(map(str, vols[0].shape)),
                 subset=params.subset, step=params.step, method=params.method))
    out = args.output
    if len(vols) == 2 and (out is None or out.suffix.lower() in (".npz", *_EXPORTS)):
        path = Path("aldic_volume.npz") if out is None else out.expanduser()
        path.parent.mkdir(parents=True, exist_ok=True)
        res = correlate_volume(vols[0], vols[1], roi=roi, params=params, block=args.block)
        _report(res, res.save(path.with_suffix(".npz")))
        if path.suffix.lower() in _EXPORTS:  # the result file, and the export beside it
            print(f"  -> {export_volume(res, path, compute_strain_volume(res)).resolve()}")
        return
    folder = Path("aldic_volume") if out is None else out.expanduser().with_suffix("")
    folder.mkdir(parents=True, exist_ok=True)
    paths = {k: folder / f"frame_{k:05d}.npz" for k in range(1, len(vols))}
    done = {k: load_result(p) for k, p in paths.items() if p.exists()}
    for k, res in track_volumes(vols, roi, args.reference, params=params, done=done,
                                block=args.block):
        if k not in done:
            _report(res, res.save(paths[k]))


def _report(res, path: Path) -> None:
    for line in res.summary().splitlines():
        print(f"  {line}")
    print(f"  -> {path.resolve()}")
