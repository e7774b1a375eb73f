"""``napari-aldic run REF DEF -o OUT.npz`` on images larger than memory: the pair
is read tile by tile and correlated block by block (``correlate_tiled``), and the
pixel size recorded in the images' metadata becomes the default units."""

from __future__ import annotations

import time
from pathlib import Path

from ..engine import ProgressEvent, Units, correlate_tiled, needs_tiling
from ..engine.io import open_image, pixel_size_of
from ..i18n import tr
from .console import CLIError, clear_bar, frame_summary, kernel_groups, precompile, progress_bar
from .masks import open_mask
from .sem import distortion_corrected


def metadata_units(inputs) -> Units | None:
    """Units from the pixel size in the first input's metadata (TIFF, ImageJ,
    OME, SEM tags, OME-Zarr), or None."""
    first = Path(inputs[0])
    if not first.exists():
        return None
    ps = pixel_size_of(first)
    if ps is None:
        return None
    print("  " + tr("pixel size {value:g} {unit} (from the {source} metadata of {name}; "
                    "--pixel-size/--unit override it)").format(
                        value=ps.value, unit=ps.unit, source=ps.source, name=first.name))
    return Units(pixel_size=ps.value, unit=ps.unit)


def units_line(units: Units, source: dict) -> str:
    """What the run takes from the images' metadata, and from where."""
    parts = []
    if "pixel_size" in source:
        parts.append(tr("pixel size {value:g} {unit} ({source})").format(
            value=units.pixel_size, unit=units.unit, source=source["pixel_size"]))
    if "frame_interval" in source:
        parts.append(tr("frame interval {value:g} {unit} ({source})").format(
            value=units.frame_interval, unit=units.time_unit, source=source["frame_interval"]))
    return "; ".join(parts) + " " + tr("(--pixel-size/--unit/--frame-interval override it)")


def _open_pair(inputs):
    """Both images opened lazily, or None when the inputs are not a pair of images."""
    if len(inputs) != 2 or any(Path(p).is_dir() and not _zarr_dir(Path(p)) for p in inputs):
        return None
    try:
        return open_image(inputs[0]), open_image(inputs[1])
    except FileNotFoundError as exc:
        raise CLIError(str(exc)) from None
    except ValueError:
        return None  # not single images (e.g. a stack): the frame reader explains


def _zarr_dir(path: Path) -> bool:
    return any((path / name).exists() for name in ("zarr.json", ".zattrs", ".zarray"))


def run_tiled_pair(args, params, units, output: Path | None) -> bool:
    """Correlate the pair block by block when it is large (or ``--tile-size``
    asks for it); False when the ordinary path should run."""
    tile = getattr(args, "tile_size", None)
    if tile == 0 or args.reference != "accumulative" or len(args.inputs) != 2:
        return False
    if tile is not None and tile < 1:
        raise CLIError(tr("--tile-size {n} must be a positive number of pixels, or 0 to "
                          "never tile").format(n=tile))
    pair = _open_pair(args.inputs)
    if pair is None:
        return False
    ref, dfm = pair
    if tile is None and not needs_tiling(ref.shape):
        ref.close()
        dfm.close()
        return False
    # the mask of a mosaic is as large as its images: sliced block by block too
    roi = None if args.roi is None else open_mask(args.roi)
    workers = getattr(args, "tile_workers", None) or 1
    if units is None:  # the pixel size recorded in the images, if any
        units = metadata_units(args.inputs)
    out = Path("aldic_result.npz") if output is None else output.expanduser()
    print(tr("{ref} ({rows} x {cols} px) and {dfm}: correlated in blocks of {tile} px, "
             "{workers} at a time, reading the images tile by tile").format(
                 ref=Path(ref.name).name, rows=ref.shape[0], cols=ref.shape[1],
                 dfm=Path(dfm.name).name, tile=tile or 2048, workers=workers))
    precompile(kernel_groups(params.method))  # a first run: in parallel processes
    t0 = time.perf_counter()
    kw = {"tile_size": tile} if tile is not None else {}
    bar = progress_bar("  " + tr("frame 1/1"))
    try:
        res = correlate_tiled(ref, dfm, roi=roi, params=params, workers=workers,
                              progress=None if bar is None else
                              lambda f, m: bar(ProgressEvent("tiles", f, message=m)), **kw)
    finally:
        ref.close()
        dfm.close()
    res = distortion_corrected(args, res)  # issue 27: --distortion
    res.meta["inputs"] = {"reference": str(args.inputs[0]), "deformed": str(args.inputs[1]),
                          "frame": 1, "roi": None if args.roi is None else str(args.roi)}
    if units is not None:
        res.meta["units"] = units.to_dict()
    out.parent.mkdir(parents=True, exist_ok=True)
    path = res.save(out)
    clear_bar()
    print(tr("frame 1/1 ({name}), {n} blocks in {secs:.1f} s:").format(
        name=Path(args.inputs[1]).name, n=res.meta["tiled"]["blocks"],
        secs=time.perf_counter() - t0))
    for line in frame_summary(res):
        print(f"  {line}")
    print(f"  -> {path.resolve()}")
    if args.plot:
        print("  " + tr("--plot is skipped for tiled runs (the figure would need the whole "
                        "image); export the result with 'napari-aldic export'"))
    return True
