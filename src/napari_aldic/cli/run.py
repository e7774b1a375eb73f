"""``napari-aldic run``: correlate a pair, a TIFF stack or a folder of images
against frame 0 and write one result file per deformed frame."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..engine import correlate, track
from ..engine.io import FrameSource, read_image, write_settings
from ..engine.viz import plot_displacement
from .console import PROG, CLIError, clear_bar, frame_summary, progress_bar, sequence_progress
from .settings import settings_from_args


def run_command(args) -> None:
    """``napari-aldic run``: every frame against frame 0, one result file each."""
    settings = settings_from_args(args, args.params)
    params, units = settings.params, settings.units
    roi = read_mask(args.roi) if args.roi is not None else None
    if args.params_out is not None:
        used = settings.replace(tracking={"reference": args.reference})
        print(f"parameters written to {write_settings(args.params_out, used).resolve()}")
    with FrameSource(args.inputs) as src:
        n = len(src)
        outputs = output_paths(args.output, list(range(1, n)), stack=n > 2)
        print(f"{PROG} run: reference {src.frame_name(0)}, {n - 1} deformed frame(s); subset "
              f"{params.subset} px, step {params.step} px, method {params.method}, "
              f"reference {args.reference}")
        t0 = time.perf_counter()

        def save(k: int, res) -> None:
            res.meta["inputs"] = {"reference": src.frame_name(0), "deformed": src.frame_name(k),
                                  "frame": k, "roi": None if args.roi is None else str(args.roi)}
            if units is not None:  # carried with the result into every export
                res.meta["units"] = units.to_dict()
            _save_result(res, outputs[k], f"frame {k}/{n - 1} ({src.frame_name(k)})",
                         src if args.plot else None)

        if n == 2 and args.reference == "accumulative":
            save(1, correlate(src[0], src[1], roi=roi, params=params,
                              progress=progress_bar("  frame 1/1")))
        else:
            # a sequence: results refer to frame 0; the previous frame is the guess
            track(src, roi=roi, params=params, reference=args.reference,
                  progress=sequence_progress(n - 1), on_frame=save)
        if n > 2:
            clear_bar()
            print(f"{n - 1} frames in {time.perf_counter() - t0:.2f} s")


def _save_result(res, path: Path, title: str, plot_src=None) -> None:
    """Save one result, print its summary and (given the frames) its figure."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path = res.save(path)
    clear_bar()
    print(f"{title}:")
    for line in frame_summary(res):
        print(f"  {line}")
    print(f"  -> {path.resolve()}")
    if plot_src is not None:
        k = res.meta["inputs"]["frame"]
        png = plot_displacement(res, path.with_suffix(".png"), image=plot_src[0],
                                title=f"frame {k}: {plot_src.frame_name(k)}")
        print(f"  -> {png.resolve()}")


def output_paths(output: Path | None, frames: list[int], stack: bool) -> dict[int, Path]:
    """Result file of every deformed frame (see the ``-o`` help); folders are
    created only when a result is saved."""
    out = Path("aldic_result.npz") if output is None else output.expanduser()
    if out.suffix.lower() == ".npz":
        if not stack:
            return {frames[0]: out}
        return {k: out.with_name(f"{out.stem}_frame{k:03d}.npz") for k in frames}
    if out.exists() and not out.is_dir():
        raise CLIError(f"output {out} exists and is not a folder; give OUT.npz or a folder")
    return {k: out / f"frame{k:03d}.npz" for k in frames}


def read_mask(path: Path) -> np.ndarray:
    """ROI mask from a ``.npy`` array or an image file (nonzero = analysed)."""
    if not path.exists():
        raise CLIError(f"no such file: {path}")
    if path.suffix.lower() == ".npy":
        try:
            m = np.load(path, allow_pickle=False)
        except Exception as exc:
            raise CLIError(f"cannot read ROI mask {path}: {exc}") from None
    else:
        m = read_image(path)
    m = np.asarray(m)
    if m.ndim == 3 and m.shape[-1] in (3, 4):  # RGB(A) mask image: any nonzero colour
        m = (m[..., :3] != 0).any(axis=-1)
    if m.ndim != 2:
        raise CLIError(f"ROI mask {path} must be a 2-D image; got shape {m.shape}")
    return m != 0
