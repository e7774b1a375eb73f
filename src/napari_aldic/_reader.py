"""npe2 reader: image stacks as one lazy layer, and napari-aldic result files.

* a multi-page TIFF (``.tif``/``.tiff``) holding a ``(frames, rows, cols)``
  series, a zarr or OME-Zarr stack folder (``.zarr``), a folder of
  BMP/PNG/TIF/JPG images (natural sort: ``img_2`` before ``img_10``), or
  several such image files chosen together, open as ONE dask-backed Image
  layer with a time axis; frames are read only when shown or analysed, and
  8/16-bit data keep their type (RGB frames become grey). The pixel size and
  frame interval the file records (OME, ImageJ, SEM tags, OME-Zarr) set the
  layer's ``scale`` and ``units``. A hyperstack with a channel axis opens as
  one layer per channel (choose the one to analyse in the widget); other
  extra axes (Z beside T, ...) are refused with a message naming them;
* a result file written by :meth:`napari_aldic.engine.DICResult.save` (``.npz``)
  opens as the result layers (no time axis); a folder of per-frame result
  files (``frame_00001.npz`` ..., as written by ``track(out_dir=...)`` or by the
  plugin's writer) opens as result layers with a time axis.

napari is not imported here.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .engine import open_stack
from .engine.io import (
    IMAGE_SUFFIXES,
    TIFF_SUFFIXES,
    ChannelChoiceError,
    FrameSource,
    grey_frame,
    image_files,
    natural_key,
)
from .i18n import tr

__all__ = ["get_reader", "read_stack", "read_results", "is_result_file"]

_FRAME_FILE = re.compile(r"frame_(\d+)\.npz$")


def is_result_file(path) -> bool:
    """True if ``path`` is a napari-aldic result ``.npz`` (header checked)."""
    path = Path(path)
    if path.suffix.lower() != ".npz" or not path.is_file():
        return False
    try:
        with np.load(path, allow_pickle=False) as z:
            if "header" not in z.files:
                return False
            return '"napari-aldic-result"' in str(z["header"])
    except Exception:
        return False


def _builtin_npz(path: Path) -> bool:
    """True for what napari's own writer makes of a result layer saved as ``.npz``
    (File > Save Selected Layers... with the default file type): one float array
    ``arr_0`` with NaN where nodes are missing, and no napari-aldic header."""
    try:
        with np.load(path, allow_pickle=False) as z:
            if z.files != ["arr_0"]:
                return False
            a = z["arr_0"]
            return a.dtype.kind == "f" and a.ndim in (2, 3) and bool(np.isnan(a).any())
    except Exception:
        return False


def _explain_builtin_npz(path):
    raise ValueError(
        tr("{name} holds only the pixels of one layer, written by "
           "napari's own image writer (the default file type of File > "
           "Save Selected Layers...), not the napari-aldic results. Save "
           "results with the DIC widget's Export section (format 'Results "
           "(.npz)'), or choose the file type 'napari-aldic results "
           "(*.npz)' in File > Save Selected Layers...; those reopen as "
           "result layers.").format(name=Path(path).name))


def _result_frames(folder: Path) -> list[tuple[int, Path]]:
    out = []
    for p in folder.iterdir():
        m = _FRAME_FILE.match(p.name)
        if m and p.is_file():
            out.append((int(m.group(1)), p))
    return sorted(out)


def _zarr_folder(path: Path) -> bool:
    return path.is_dir() and any((path / n).is_file()
                                 for n in ("zarr.json", ".zarray", ".zattrs", ".zgroup"))


def _file_stack(path: Path) -> bool:
    """True for a TIFF or zarr/OME-Zarr folder holding a stack of at least
    two grey frames (a hyperstack with a channel axis included); single
    images and RGB stacks are left to napari's own reader."""
    try:
        with open_stack(path) as src:
            return len(src.frame_shape) == 2
    except ChannelChoiceError:
        return True  # one layer per channel
    except (OSError, ValueError):
        return False


def get_reader(path):
    """Return a reader function if ``path`` is something this plugin opens."""
    if isinstance(path, (list, tuple)):
        paths = [Path(p) for p in path]
        if len(paths) == 1:
            return get_reader(paths[0])
        if paths and all(p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES for p in paths):
            return read_stack
        if paths and all(is_result_file(p) for p in paths):
            return read_results
        return None
    path = Path(path)
    if _zarr_folder(path):
        return read_stack if _file_stack(path) else None
    if path.is_dir():
        if _result_frames(path):
            return read_results
        return read_stack if len(image_files(path)) >= 2 else None
    suffix = path.suffix.lower()
    if suffix == ".npz":
        if not path.is_file():  # a named pipe or device would block np.load
            return None
        if is_result_file(path):
            return read_results
        return _explain_builtin_npz if _builtin_npz(path) else None
    if suffix in TIFF_SUFFIXES and path.is_file() and _file_stack(path):
        return read_stack
    return None


# ----------------------------------------------------------------- stacks
def _lazy_stack(read_frame, n: int, first: np.ndarray, label: str):
    """A (n, H, W) dask array whose frame k is ``read_frame(k)``."""
    import dask
    import dask.array as da

    first = grey_frame(first)
    shape, dtype = first.shape, first.dtype

    def load(k: int) -> np.ndarray:
        img = grey_frame(read_frame(k))
        if img.shape != shape:
            raise ValueError(tr("{label}: frame {k} has shape {shape}, frame 0 has {shape2}; "
                                "all frames of a stack must have the same size").format(
                                    label=label, k=k, shape=img.shape, shape2=shape))
        return img.astype(dtype, copy=False)

    frames = [da.from_delayed(dask.delayed(load)(k), shape=shape, dtype=dtype) for k in range(n)]
    return da.stack(frames), first


def _stack_geometry(src) -> dict:
    """Layer ``scale`` and ``units`` from the pixel size and frame interval
    the stack's file records (pixels and frames without them)."""
    units = src.units
    if units is None:
        return {}
    p, dt = units.pixel_size, units.frame_interval
    length = _axis_unit("pixel" if units.unit == "px" else units.unit)
    return {"scale": (dt or 1.0, p, p),
            "units": (_axis_unit(units.time_unit) if dt else "pixel", length, length)}


def _stack_layer(data, first: np.ndarray, name: str, meta: dict, src=None):
    lo, hi = float(np.min(first)), float(np.max(first))
    if np.issubdtype(first.dtype, np.integer):
        info = np.iinfo(first.dtype)
        lo, hi = (lo, hi) if hi > lo else (float(info.min), float(info.max))
    elif not hi > lo:
        lo, hi = lo, lo + 1.0
    kwargs = {"name": name, "metadata": meta, "contrast_limits": (lo, hi),
              "axis_labels": ("t", "y", "x")}
    if src is not None:
        kwargs.update(_stack_geometry(src))
        if src.units is not None:
            meta.update(units=src.units.to_dict(), units_source=src.units_source)
    return [(data, kwargs, "image")]


def _channel_layers(path: Path, n_channels: int):
    """One lazy layer per channel of a hyperstack, named ``STACK [channel c]``."""
    layers = []
    for c in range(n_channels):
        src = FrameSource(path, channel=c)
        data, first = _lazy_stack(src.__getitem__, len(src), src[0], str(path))
        name = f"{path.stem if path.is_file() else path.name} [channel {c}]"
        layers += _stack_layer(data, first, name, {"source": str(path), "channel": c,
                                                    "axes": src.axes}, src)
    return layers


def read_stack(path):
    """A TIFF stack, an image folder or a list of image files (in natural
    order) as one lazy layer."""
    if isinstance(path, (list, tuple)) and len(path) > 1:
        files = sorted((Path(p) for p in path), key=natural_key)
        src = open_stack(files)
        label, name = str(files[0].parent), files[0].parent.name or files[0].stem
        meta = {"source": [str(f) for f in files], "frames": [f.name for f in files]}
    else:
        path = Path(path[0] if isinstance(path, (list, tuple)) else path)
        try:
            src = open_stack(path)  # natural sort, one page or file per request
        except ChannelChoiceError as exc:
            return _channel_layers(path, exc.n_channels)
        label, name = str(path), path.stem if path.is_file() else path.name
        meta = {"source": str(path)}
        if path.is_dir() and not _zarr_folder(path):
            meta["frames"] = [p.name for p in image_files(path)]
    data, first = _lazy_stack(src.__getitem__, len(src), src[0], label)
    return _stack_layer(data, first, name, meta, src)


# ----------------------------------------------------------------- results
def _load_analysis(paths: list[Path], folder: bool):
    from ._analysis import Analysis, StrainSettings, zero_field
    from .engine import compute_strain, load_result

    loaded = [load_result(p) for p in paths]
    settings = StrainSettings()
    if not folder and len(loaded) == 1:
        res = loaded[0]
        frames, n_frames, results = [int(res.meta.get("frame", 1))], None, [res]
    else:
        ks = [int(r.meta.get("frame", i + 1)) for i, r in enumerate(loaded)]
        if folder:
            ks = [int(_FRAME_FILE.match(p.name).group(1)) for p in paths]
        order = np.argsort(ks)
        ks = [ks[i] for i in order]
        results = [loaded[i] for i in order]
        if ks[0] != 0:
            # the reference frame itself is not stored: show it as a zero field
            ref = min(int(r.meta.get("reference_frame", 0)) for r in results)
            ref = ref if ref < ks[0] else 0
            ks.insert(0, ref)
            results.insert(0, zero_field(results[0]))
        frames, n_frames = ks, ks[-1] + 1
    strains = []
    for r in results:
        try:
            strains.append(compute_strain(r, window=settings.window, method=settings.method,
                                          measure=settings.measure))
        except ValueError:
            strains.append(None)
    return Analysis(results=results, strains=strains, frames=frames, n_frames=n_frames,
                    params=results[-1].params, strain=settings,
                    source=str(paths[0].parent if folder else paths[0]))


def _axis_unit(name: str) -> str:
    """``name`` if napari (pint) understands it as a unit, else ``"pixel"``."""
    try:
        import pint

        pint.get_application_registry().Unit(name)
        return name
    except Exception:
        return "pixel"


def read_results(path):
    """Result file(s) or a folder of ``frame_#####.npz`` files as result layers."""
    from ._layers import Display, Geometry, analysis_layers

    if isinstance(path, (list, tuple)):
        paths = [Path(p) for p in path]
        folder = False
    else:
        p = Path(path)
        folder = p.is_dir()
        paths = [q for _, q in _result_frames(p)] if folder else [p]
    if not paths:
        raise ValueError(tr("no napari-aldic result files in {path}").format(path=path))
    from .engine import Units

    analysis = _load_analysis(paths, folder)
    # physical units saved with the results (``meta["units"]``) set scale and values
    units = None
    for r in analysis.results:
        try:
            units = Units.from_meta(r.meta)
        except ValueError:
            units = None
        if units is not None:
            break
    units = units or Units()
    p = units.pixel_size
    length = _axis_unit("pixel" if units.unit == "px" else units.unit)
    dt = units.frame_interval
    if analysis.n_frames:
        geometry = Geometry((dt or 1.0, p, p), (0.0, 0.0, 0.0),
                            (_axis_unit(units.time_unit) if dt else "pixel", length, length),
                            ("t", "y", "x"))
    else:
        geometry = Geometry((p, p), (0.0, 0.0), (length, length), ("y", "x"))
    display = Display(length_scale=p, length_unit=units.unit, frame_interval=dt,
                      time_unit=units.time_unit)
    return analysis_layers(analysis, geometry, display)
