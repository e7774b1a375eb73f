"""Command line interface: ``napari-aldic demo`` and ``napari-aldic run``.

``demo`` renders a synthetic speckle pair with exact truth, analyses it and
reports the error; ``run`` analyses an image pair, a multi-page TIFF stack or a
folder of images (frame 0 is the reference; every other frame is correlated
against it) and writes one ``.npz`` result per frame.

Errors in the input (missing or unreadable files, bad parameters, images the
engine rejects) print ``napari-aldic: error: <message>`` and exit with code 2.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from . import __version__

__all__ = ["main", "build_parser", "read_image", "read_mask", "FrameSource"]

PROG = "napari-aldic"
TIFF_SUFFIXES = {".tif", ".tiff"}
IMAGE_SUFFIXES = TIFF_SUFFIXES | {".png", ".bmp", ".jpg", ".jpeg", ".jp2", ".pgm"}
#: run options that override fields of the parameter file (dest -> DICParams field)
OVERRIDES = ("subset", "step", "search", "search_max", "method", "interpolation", "n_threads")


class CLIError(Exception):
    """A user-facing error: printed as one line, no traceback."""


# ----------------------------------------------------------------- parsing
def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``napari-aldic``."""
    from ._cases import FIELDS

    parser = argparse.ArgumentParser(
        prog=PROG, description="2-D digital image correlation (napari-aldic engine).")
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    demo = sub.add_parser(
        "demo", help="analyse a synthetic speckle pair with exact truth",
        description="Render a synthetic speckle pair with a known displacement field, "
                    "correlate it, report the error against the truth and write the "
                    "images, the result and a figure into a folder.")
    demo.add_argument("--out", type=Path, default=Path("aldic_demo"),
                      help="output folder (default: ./aldic_demo)")
    demo.add_argument("--size", type=int, default=512, help="image size N for N x N (default 512)")
    demo.add_argument("--noise", type=float, default=1.0, metavar="GL",
                      help="Gaussian noise std in grey levels, 8-bit images (default 1)")
    demo.add_argument("--field", choices=FIELDS, default=FIELDS[0],
                      help="displacement field (default: strain = 1%% strain + 0.5 deg "
                           "rotation + sub-pixel translation)")
    demo.add_argument("--subset", type=int, default=31, help="subset full width, px (default 31)")
    demo.add_argument("--step", type=int, default=8, help="node spacing, px (default 8)")
    demo.add_argument("--method", choices=("local", "aldic"), default="local")
    demo.add_argument("--seed", type=int, default=0, help="speckle pattern seed (default 0)")

    run = sub.add_parser(
        "run", help="analyse an image pair, a TIFF stack or a folder of images",
        description="Correlate images against a reference. INPUT is either REF DEF "
                    "[DEF ...] (one image per file), or one multi-page TIFF stack or one "
                    "folder of images (natural sort order); frame 0 is the reference.")
    run.add_argument("inputs", nargs="+", type=Path, metavar="INPUT",
                     help="REF DEF [DEF ...], or STACK.tif, or FOLDER")
    run.add_argument("--roi", type=Path, metavar="MASK",
                     help="ROI mask: image file (nonzero = analysed) or .npy array")
    run.add_argument("--params", type=Path, metavar="FILE.json",
                     help="JSON object of DICParams fields; options below override it")
    run.add_argument("--subset", type=int, help="subset full width in px, odd (default 31)")
    run.add_argument("--step", type=int, help="node spacing in px (default 8)")
    run.add_argument("--search", type=int, help="initial search half-range in px (default 20)")
    run.add_argument("--search-max", type=int, dest="search_max",
                     help="largest search half-range in px (default: automatic)")
    run.add_argument("--method", choices=("local", "aldic"), help="solver (default local)")
    run.add_argument("--interpolation", choices=("cubic", "quintic"),
                     help="B-spline order (default cubic)")
    run.add_argument("--threads", type=int, dest="n_threads", help="Numba threads (default all)")
    run.add_argument("-o", "--output", type=Path, metavar="OUT",
                     help="OUT.npz (a stack writes OUT_frame###.npz) or a folder "
                          "(writes frame###.npz); default ./aldic_result.npz")
    run.add_argument("--plot", action="store_true",
                     help="also write a PNG figure of u and v beside each result")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``napari-aldic`` console script; returns the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, usage errors
        return int(exc.code or 0)
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            if args.command == "demo":
                run_demo(args)
            else:
                run_analysis(args)
        except BrokenPipeError:  # stdout piped into a program that stopped reading
            _silence_stdout()
            return 1
        except (CLIError, ValueError, OSError, NotImplementedError) as exc:
            msg = str(exc) if not isinstance(exc, FileNotFoundError) or not exc.filename \
                else f"no such file: {exc.filename}"
            msg = " ".join(line.strip() for line in msg.splitlines() if line.strip())
            print(f"{PROG}: error: {msg}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print(f"{PROG}: interrupted (results already written are kept)", file=sys.stderr)
            return 130
    return 0


def _silence_stdout() -> None:
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass


def _show_warning(message, category, filename, lineno, file=None, line=None):
    print(f"{PROG}: warning: {message}", file=sys.stderr)


def _progress(prefix: str):
    """A progress callback drawing a bar on an interactive stderr, else None."""
    if not sys.stderr.isatty():
        return None

    def report(frac: float, msg: str) -> None:
        n = int(round(30 * frac))
        end = "\n" if frac >= 1 else ""
        print(f"\r{prefix} [{'#' * n}{'.' * (30 - n)}] {frac:4.0%} {msg:<40.40}", end=end,
              file=sys.stderr, flush=True)

    return report


# ----------------------------------------------------------------- demo
def run_demo(args) -> None:
    """``napari-aldic demo``: synthetic pair, analysis, error report, files."""
    import tifffile

    from ._cases import make_case
    from .engine import correlate
    from .engine.figures import plot_displacement

    out = args.out.expanduser().resolve()
    case = make_case(args.field, (args.size, args.size), noise=args.noise, seed=args.seed)
    print(f"{PROG} demo: {args.size} x {args.size} synthetic speckle pair, 8-bit, "
          f"noise {args.noise:g} grey levels")
    print(f"  field: {case.description}")
    res = correlate(case.reference, case.deformed, roi=case.roi, subset=args.subset,
                    step=args.step, method=args.method, progress=_progress("  correlate"))
    print("  " + _counts_line(res))
    ut, vt = case.field.displacement(res.x, res.y)
    sel = res.valid
    if not sel.any():
        raise CLIError("no node converged; nothing to compare with the truth")
    eu, ev = res.u[sel] - ut[sel], res.v[sel] - vt[sel]
    stats = {"rmse_u": float(np.sqrt(np.mean(eu**2))), "max_u": float(np.abs(eu).max()),
             "rmse_v": float(np.sqrt(np.mean(ev**2))), "max_v": float(np.abs(ev).max())}
    print(f"  error against the exact truth over the {res.n_valid} valid nodes:")
    print(f"    u: RMSE {stats['rmse_u']:.4f} px, max {stats['max_u']:.4f} px")
    print(f"    v: RMSE {stats['rmse_v']:.4f} px, max {stats['max_v']:.4f} px")

    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, img in (("reference.tif", case.reference), ("deformed.tif", case.deformed)):
        tifffile.imwrite(out / name, img, photometric="minisblack")
        written.append(name)
    roi_opt = ""
    if case.roi is not None:
        tifffile.imwrite(out / "roi.tif", case.roi.astype(np.uint8) * 255,
                         photometric="minisblack")
        written.append("roi.tif")
        roi_opt = f" --roi {out / 'roi.tif'}"
    res.meta["demo"] = {"field": args.field, "description": case.description,
                        "size": args.size, "noise": args.noise, "seed": args.seed, **stats}
    res.save(out / "result.npz")
    (out / "params.json").write_text(json.dumps(res.params.to_dict(), indent=2) + "\n")
    plot_displacement(res, out / "displacement.png", truth=case.field, image=case.reference,
                      title=f"demo '{args.field}': {case.description}")
    written += ["result.npz", "params.json", "displacement.png"]
    print(f"  wrote {', '.join(written)} to")
    print(f"  {out}")
    print(f"  analyse them again with: {PROG} run {out / 'reference.tif'} "
          f"{out / 'deformed.tif'}{roi_opt} --params {out / 'params.json'} -o result.npz")


# ----------------------------------------------------------------- input
def _natural_key(path: Path):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def _check_file(path: Path) -> Path:
    if not path.exists():
        raise CLIError(f"no such file: {path}")
    if path.is_dir():
        raise CLIError(f"{path} is a folder; expected an image file")
    return path


def read_image(path) -> np.ndarray:
    """Read an image file: tifffile for .tif/.tiff, scikit-image otherwise."""
    path = _check_file(Path(path))
    try:
        with warnings.catch_warnings():  # readers' own deprecation chatter
            warnings.simplefilter("ignore", DeprecationWarning)
            warnings.simplefilter("ignore", FutureWarning)
            if path.suffix.lower() in TIFF_SUFFIXES:
                import tifffile

                return np.asarray(tifffile.imread(path))
            from skimage import io as skio

            return np.asarray(skio.imread(path))
    except Exception as exc:  # any reader failure is a bad input file
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise CLIError(f"cannot read image {path}: {first}") from None


def _as_single_frame(img: np.ndarray, path: Path) -> np.ndarray:
    """Reject a stack where one image is expected (RGB(A) passes through)."""
    if img.ndim == 3 and img.shape[-1] not in (3, 4):
        raise CLIError(f"{path} holds {img.shape[0]} frames; give a stack as the only input")
    return img


def read_mask(path) -> np.ndarray:
    """ROI mask from a ``.npy`` array or an image file (nonzero = analysed)."""
    path = _check_file(Path(path))
    if path.suffix.lower() == ".npy":
        try:
            m = np.load(path, allow_pickle=False)
        except Exception as exc:
            raise CLIError(f"cannot read ROI mask {path}: {exc}") from None
    else:
        m = _as_single_frame(read_image(path), path)
    m = np.asarray(m)
    if m.ndim == 3:  # RGB(A) mask image: any nonzero colour channel
        m = (m[..., :3] != 0).any(axis=-1)
    if m.ndim != 2:
        raise CLIError(f"ROI mask {path} must be a 2-D image; got shape {m.shape}")
    return m != 0


class FrameSource:
    """Frames to analyse, read one at a time.

    ``FrameSource(paths)``: one path that is a multi-page TIFF stack or a
    folder of images, or several paths with one image each. ``len()`` is the
    number of frames, ``src[k]`` reads frame k, ``src.name(k)`` names it.
    """

    def __init__(self, paths: list[Path]):
        self._tif = None
        self._stack = None
        self._files: list[Path] = []
        if len(paths) == 1:
            p = paths[0]
            if p.is_dir():
                self._files = sorted((f for f in p.iterdir()
                                      if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES),
                                     key=_natural_key)
                if len(self._files) < 2:
                    raise CLIError(f"folder {p} holds {len(self._files)} image(s); "
                                   "need a reference and at least one deformed image")
            elif _check_file(p).suffix.lower() in TIFF_SUFFIXES:
                self._open_tiff(p)
            else:
                raise CLIError(f"{p} is a single image; give REF DEF, a multi-page TIFF "
                               "stack or a folder of images")
        else:
            self._files = [_check_file(p) for p in paths]
        self.label = str(paths[0]) if len(paths) == 1 else None

    def _open_tiff(self, path: Path) -> None:
        import tifffile

        try:
            self._tif = tifffile.TiffFile(path)
            series = self._tif.series[0]
        except Exception as exc:
            raise CLIError(f"cannot read TIFF stack {path}: {exc}") from None
        shape, axes = tuple(series.shape), series.axes
        nframe_axes = len(shape) - (3 if axes.endswith("S") else 2)
        self._n = int(np.prod(shape[:nframe_axes])) if nframe_axes > 0 else 1
        self._frame_shape = shape[nframe_axes:]
        if self._n < 2:
            raise CLIError(f"{path} holds a single frame (shape {shape}); a stack needs a "
                           "reference and at least one deformed frame")
        self._series = series
        # one page per frame: read pages lazily; otherwise read the whole series once
        if not (len(series.pages) == self._n
                and tuple(series.pages[0].shape) == self._frame_shape):
            self._stack = series.asarray().reshape(self._n, *self._frame_shape)
        self._path = path

    def __len__(self) -> int:
        return len(self._files) if self._tif is None else self._n

    def __getitem__(self, k: int) -> np.ndarray:
        if self._tif is None:
            return _as_single_frame(read_image(self._files[k]), self._files[k])
        if self._stack is not None:
            return self._stack[k]
        try:
            return self._series.pages[k].asarray()
        except Exception as exc:
            raise CLIError(f"cannot read frame {k} of {self._path}: {exc}") from None

    def name(self, k: int) -> str:
        return str(self._files[k]) if self._tif is None else f"{self._path}[{k}]"

    def close(self) -> None:
        if self._tif is not None:
            self._tif.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def load_params(args):
    """DICParams from ``--params`` (JSON) with command-line options overriding it."""
    from .engine import DICParams

    base = {}
    if args.params is not None:
        path = _check_file(args.params)
        try:
            base = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise CLIError(f"parameter file {path} is not valid JSON: {exc}") from None
        if not isinstance(base, dict):
            raise CLIError(f"parameter file {path} must hold a JSON object of DICParams fields")
    changes = {k: getattr(args, k) for k in OVERRIDES if getattr(args, k) is not None}
    return DICParams.from_dict({**base, **changes})


def _output_paths(output: Path | None, frames: list[int], stack: bool) -> dict[int, Path]:
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


# ----------------------------------------------------------------- run
def _counts_line(res) -> str:
    total = float(res.meta.get("timing", {}).get("total", float("nan")))
    pct = 100.0 * res.n_valid / max(len(res), 1)
    return (f"{len(res)} nodes, {res.n_valid} valid ({pct:.1f} %), {total:.3f} s "
            f"({len(res) / max(total, 1e-9):,.0f} POI/s)")


def frame_summary(res) -> list[str]:
    """Lines describing one result: counts, time, displacement range, flags."""
    lines = [_counts_line(res)]
    v = res.valid
    if v.any():
        lines.append(f"u mean {res.u[v].mean():+.4f} px [{res.u[v].min():+.3f}, "
                     f"{res.u[v].max():+.3f}]; v mean {res.v[v].mean():+.4f} px "
                     f"[{res.v[v].min():+.3f}, {res.v[v].max():+.3f}]; "
                     f"median ZNCC {np.median(res.zncc[v]):.4f}")
    flagged = {k: c for k, c in res.reason_counts().items() if k != "converged"}
    if flagged:
        lines.append("flagged: " + ", ".join(f"{k}: {c}" for k, c in flagged.items()))
    return lines


def run_analysis(args) -> None:
    """``napari-aldic run``: every frame against frame 0, one result file each."""
    from .engine import correlate
    from .engine.figures import plot_displacement

    params = load_params(args)
    roi = read_mask(args.roi) if args.roi is not None else None
    with FrameSource(args.inputs) as src:
        n = len(src)
        frames = list(range(1, n))
        outputs = _output_paths(args.output, frames, stack=n > 2)
        reference = src[0]
        print(f"{PROG} run: reference {src.name(0)}, {n - 1} deformed frame(s); subset "
              f"{params.subset} px, step {params.step} px, method {params.method}")
        t0 = time.perf_counter()
        for k in frames:
            deformed = src[k]
            res = correlate(reference, deformed, roi=roi, params=params,
                            progress=_progress(f"  frame {k}/{n - 1}"))
            res.meta["inputs"] = {"reference": src.name(0), "deformed": src.name(k),
                                  "frame": k, "roi": None if args.roi is None else str(args.roi)}
            outputs[k].parent.mkdir(parents=True, exist_ok=True)
            path = res.save(outputs[k])
            print(f"frame {k}/{n - 1} ({src.name(k)}):")
            for line in frame_summary(res):
                print(f"  {line}")
            print(f"  -> {path.resolve()}")
            if args.plot:
                png = plot_displacement(res, path.with_suffix(".png"), image=reference,
                                        title=f"frame {k}: {src.name(k)}")
                print(f"  -> {png.resolve()}")
        if n > 2:
            print(f"{n - 1} frames in {time.perf_counter() - t0:.2f} s")


if __name__ == "__main__":  # python -m napari_aldic.cli
    sys.exit(main())
