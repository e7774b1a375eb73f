"""Command line interface: ``napari-aldic demo``, ``run``, ``export`` and ``params``.

``demo`` renders a synthetic speckle pair with exact truth, analyses it and
reports the error; ``run`` analyses an image pair, a multi-page TIFF stack or a
folder of images (frame 0 is the reference; every other frame is correlated
against it) and writes one ``.npz`` result per frame; ``export`` turns results
(a ``.npz``, several, or a run folder) into MATLAB, CSV, VTK, DaVis text,
PNG/GIF/MP4 images and a PDF report; ``params`` writes a parameter file.

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
OVERRIDES = ("subset", "step", "search", "search_max", "method", "interpolation", "n_threads",
             "smooth", "second_order_warp")
EXPORT_FORMATS = ("mat", "csv", "vtu", "davis", "png", "gif", "mp4", "pdf")


class CLIError(Exception):
    """A user-facing error: printed as one line, no traceback."""


# ----------------------------------------------------------------- parsing
def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``napari-aldic``."""
    from .engine.synthetic import CASES as FIELDS

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
    _add_param_options(run)
    run.add_argument("-o", "--output", type=Path, metavar="OUT",
                     help="OUT.npz (a stack writes OUT_frame###.npz) or a folder "
                          "(writes frame###.npz); default ./aldic_result.npz")
    run.add_argument("--plot", action="store_true",
                     help="also write a PNG figure of u and v beside each result")
    run.add_argument("--reference", choices=("accumulative", "incremental"),
                     default="accumulative",
                     help="stacks: correlate every frame against frame 0 (accumulative) "
                          "or against the previous frame, composed back to frame 0 "
                          "(incremental); results always refer to frame 0")
    run.add_argument("--params-out", type=Path, metavar="FILE.json", dest="params_out",
                     help="also write the complete parameters used (file and options "
                          "merged) to FILE.json, for --params of a later run")
    _add_unit_options(run)

    prm = sub.add_parser(
        "params", help="write a parameter file (defaults, a file, and options)",
        description="Write the analysis parameters as readable JSON: the defaults, or "
                    "--params FILE, with the options below applied. Use the file with "
                    "'napari-aldic run --params FILE'.")
    prm.add_argument("output", type=Path, metavar="OUT.json", help="file to write")
    _add_param_options(prm)
    _add_unit_options(prm)

    exp = sub.add_parser(
        "export", help="export results to MAT, CSV, VTU, DaVis text, PNG, GIF, MP4, PDF",
        description="Export results: one result .npz, several, a .mat written by "
                    "export, or a run folder (written by 'run -o FOLDER' or track). "
                    "Outputs are named OUT.<ext> (images OUT_<field>.png, one per frame "
                    "for a sequence: OUT_<field>_frame#####.png). See docs/exports.md.")
    exp.add_argument("inputs", nargs="+", type=Path, metavar="INPUT",
                     help="RESULT.npz [RESULT.npz ...], RESULT.mat or RUN_FOLDER")
    exp.add_argument("--to", nargs="+", required=True, metavar="FORMAT", dest="formats",
                     help=f"one or more of: {', '.join(EXPORT_FORMATS)} (comma or space "
                          "separated)")
    exp.add_argument("-o", "--output", type=Path, metavar="OUT",
                     help="output name without extension, or a folder (default: "
                          "RUN_FOLDER/export or RESULT without .npz)")
    exp.add_argument("--field", nargs="+", default=None, metavar="FIELD",
                     help="field(s) drawn in png/gif/mp4 (default u): u, v, magnitude, "
                          "exx, eyy, exy, e1, e2, max_shear, von_mises, rotation, zncc, "
                          "vx, vy, exx_rate, eyy_rate, exy_rate")
    exp.add_argument("--frames", nargs="+", type=int, metavar="K",
                     help="frame numbers to export (default all; the report picks up to 4)")
    exp.add_argument("--line", nargs=4, type=float, metavar=("X0", "Y0", "X1", "Y1"),
                     help="profile line for the PDF report, in pixels")
    _add_unit_options(exp)
    exp.add_argument("--settings", type=Path, metavar="FILE.json",
                     help="take units and strain settings from a parameter file")
    exp.add_argument("--no-strain", action="store_true", dest="no_strain",
                     help="do not compute strain")
    exp.add_argument("--strain-window", type=int, dest="strain_window", metavar="N",
                     help="strain window in nodes, odd >= 3 (default 5)")
    exp.add_argument("--strain-method", choices=("plane_fit", "fem"), dest="strain_method")
    exp.add_argument("--strain-measure", dest="strain_measure",
                     choices=("green_lagrange", "infinitesimal", "euler_almansi"))
    exp.add_argument("--fps", type=float, default=4.0, help="GIF/MP4 frames per second")
    exp.add_argument("--encoding", choices=("binary", "ascii"), default="binary",
                     help="VTU data encoding (default binary = base64)")
    exp.add_argument("--dpi", type=int, default=150, help="PNG resolution (default 150)")
    return parser


def _add_unit_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--pixel-size", type=float, dest="pixel_size", metavar="S",
                   help="length of one pixel in --unit (e.g. 0.05 with --unit um)")
    p.add_argument("--unit", help="length unit name (default px)")
    p.add_argument("--frame-interval", type=float, dest="frame_interval", metavar="DT",
                   help="time between frames in --time-unit (adds time, velocity and "
                        "strain-rate columns)")
    p.add_argument("--time-unit", dest="time_unit", help="time unit name (default s)")


def _add_param_options(p: argparse.ArgumentParser) -> None:
    """Options overriding fields of the parameter file (see ``OVERRIDES``)."""
    p.add_argument("--params", type=Path, metavar="FILE.json",
                   help="parameter file (JSON: DICParams fields, or a file written by "
                        "'napari-aldic params' / --params-out); options below override it")
    p.add_argument("--subset", type=int, help="subset full width in px, odd (default 31)")
    p.add_argument("--step", type=int, help="node spacing in px (default 8)")
    p.add_argument("--search", type=int, help="initial search half-range in px (default 20)")
    p.add_argument("--search-max", type=int, dest="search_max",
                   help="largest search half-range in px (default: automatic)")
    p.add_argument("--method", choices=("local", "aldic"), help="solver (default local)")
    p.add_argument("--interpolation", choices=("auto", "cubic", "quintic"),
                   help="B-spline order (default cubic)")
    p.add_argument("--threads", type=int, dest="n_threads", help="Numba threads (default all)")
    p.add_argument("--smooth", type=_smooth_arg, metavar="auto|PX",
                   help="AL-DIC thin-plate smoothing length in px; 'auto' (default) picks it "
                        "from the image noise, 0 = the paper's plain Algorithm 1")
    p.add_argument("--affine-warp", action="store_const", const=False,
                   dest="second_order_warp",
                   help="AL-DIC: never bend subsets with the global field's curvature")


def _smooth_arg(text: str):
    if text == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--smooth {text!r}: give 'auto' or a length in "
                                         "pixels (e.g. 8)") from None
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"--smooth {text!r}: the length must be >= 0 px")
    return value


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
            elif args.command == "export":
                return run_export(args)
            elif args.command == "params":
                run_params(args)
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

    from .engine.synthetic import make_case
    from .engine import correlate
    from .engine.viz import plot_displacement

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
    """DICParams from ``--params`` (JSON) with command-line options overriding it.

    The file is a JSON object of DICParams fields, or a settings file written by
    ``napari-aldic params`` / ``--params-out`` (its ``"params"`` section).
    """
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
        if isinstance(base.get("params"), dict):  # settings file: the "params" section
            base = base["params"]
    changes = {k: getattr(args, k) for k in OVERRIDES if getattr(args, k) is not None}
    return DICParams.from_dict({**base, **changes})


def _units_from_args(args, base=None):
    """Units from --pixel-size/--unit/--frame-interval/--time-unit over ``base``
    (None when nothing is given)."""
    from .engine import Units

    given = {k: getattr(args, k) for k in ("pixel_size", "unit", "frame_interval", "time_unit")
             if getattr(args, k, None) is not None}
    if not given:
        return base
    return Units.from_dict({**(base.to_dict() if base is not None else {}), **given})


def _settings_extras(path):
    """(units, strain) of a settings file given with ``--params``/``--settings``."""
    if path is None:
        return None, None
    from .engine.io import load_settings

    s = load_settings(_check_file(path))
    return s["units"], s["strain"]


def run_params(args) -> None:
    """``napari-aldic params OUT.json``: write the parameters (and units)."""
    from .engine import save_params

    params = load_params(args)
    units0, strain = _settings_extras(args.params)
    units = _units_from_args(args, units0)
    path = save_params(args.output, params, units=units, strain=strain)
    print(f"wrote parameters to {path.resolve()}")
    print(f"use them with: {PROG} run INPUT ... --params {path}")


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
    if res.aldic_summary():
        lines.append(res.aldic_summary())
    flagged = {k: c for k, c in res.reason_counts().items() if k != "converged"}
    if flagged:
        lines.append("flagged: " + ", ".join(f"{k}: {c}" for k, c in flagged.items()))
    return lines


def run_analysis(args) -> None:
    """``napari-aldic run``: every frame against frame 0, one result file each."""
    from .engine import correlate, track
    from .engine.viz import plot_displacement

    params = load_params(args)
    roi = read_mask(args.roi) if args.roi is not None else None
    units0, strain = _settings_extras(args.params)
    units = _units_from_args(args, units0)
    if getattr(args, "params_out", None) is not None:
        from .engine import save_params

        written = save_params(args.params_out, params, units=units, strain=strain)
        print(f"parameters written to {written.resolve()}")
    with FrameSource(args.inputs) as src:
        n = len(src)
        frames = list(range(1, n))
        outputs = _output_paths(args.output, frames, stack=n > 2)
        print(f"{PROG} run: reference {src.name(0)}, {n - 1} deformed frame(s); subset "
              f"{params.subset} px, step {params.step} px, method {params.method}, "
              f"reference {args.reference}")
        t0 = time.perf_counter()

        def save(k: int, res) -> None:
            res.meta["inputs"] = {"reference": src.name(0), "deformed": src.name(k),
                                  "frame": k, "roi": None if args.roi is None else str(args.roi)}
            if units is not None:  # carried with the result into every export
                res.meta["units"] = units.to_dict()
            outputs[k].parent.mkdir(parents=True, exist_ok=True)
            path = res.save(outputs[k])
            _clear_bar()
            print(f"frame {k}/{n - 1} ({src.name(k)}):")
            for line in frame_summary(res):
                print(f"  {line}")
            print(f"  -> {path.resolve()}")
            if args.plot:
                png = plot_displacement(res, path.with_suffix(".png"), image=src[0],
                                        title=f"frame {k}: {src.name(k)}")
                print(f"  -> {png.resolve()}")

        if n == 2 and args.reference == "accumulative":
            save(1, correlate(src[0], src[1], roi=roi, params=params,
                              progress=_progress("  frame 1/1")))
        else:
            # a sequence: results refer to frame 0; the previous frame is the guess
            track(_StackView(src), roi=roi, params=params, reference=args.reference,
                  progress=_sequence_progress(n - 1), on_frame=save)
        if n > 2:
            _clear_bar()
            print(f"{n - 1} frames in {time.perf_counter() - t0:.2f} s")


class _StackView:
    """The CLI's frame source seen as a (T, H, W) array-like by ``track``."""

    ndim = 3

    def __init__(self, src):
        self._src = src
        first = src[0]
        self.shape = (len(src),) + tuple(first.shape)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, k):
        return self._src[k]


def _clear_bar() -> None:
    if sys.stderr.isatty():
        print("\r" + " " * 100 + "\r", end="", file=sys.stderr, flush=True)


def _sequence_progress(n_frames: int):
    """Progress bar over frames with the estimated time left (interactive stderr)."""
    if not sys.stderr.isatty():
        return None
    t0 = time.perf_counter()

    def report(k: int, frac: float, msg: str) -> None:
        el = time.perf_counter() - t0
        left = el * (1 - frac) / frac if frac > 0 else float("nan")
        eta = "--:--" if not np.isfinite(left) else f"{int(left) // 60:02d}:{int(left) % 60:02d}"
        done = int(round(frac * n_frames))
        bar = int(round(30 * frac))
        print(f"\r  [{'#' * bar}{'.' * (30 - bar)}] {done}/{n_frames} frames, "
              f"{el:5.1f} s, {eta} left  {msg:<28.28}", end="", file=sys.stderr, flush=True)

    return report


# ----------------------------------------------------------------- export
def _export_base(inputs: list[Path], output: Path | None) -> Path:
    if output is not None:
        out = output.expanduser()
        return out / "export" if out.is_dir() else out
    first = inputs[0].expanduser()
    if len(inputs) == 1 and first.is_dir():
        return first / "export"
    if len(inputs) == 1:
        return first.with_suffix("")
    return first.parent / "export"


def run_export(args) -> int:
    """``napari-aldic export``: every requested format; returns the exit code."""
    from .engine import EncoderNotFoundError, export_result

    formats = [f.strip().lower() for item in args.formats for f in item.split(",") if f.strip()]
    bad = [f for f in formats if f not in EXPORT_FORMATS]
    if bad:
        raise CLIError(f"unknown export format(s) {bad}; choose from {', '.join(EXPORT_FORMATS)}")
    for p in args.inputs:
        if not p.expanduser().exists():
            raise CLIError(f"no such file or folder: {p}")
    if len(args.inputs) == 1:
        data = args.inputs[0].expanduser()
    else:
        if any(p.is_dir() for p in args.inputs):
            raise CLIError("give one run folder, or one or more result files")
        data = [p.expanduser() for p in args.inputs]
    from .engine.io import collect_frames

    units0, strain0 = _settings_extras(args.settings)
    units = _units_from_args(args, units0)
    if args.no_strain:
        strain = False
    else:
        strain = dict(strain0 or {})
        for k, opt in (("window", "strain_window"), ("method", "strain_method"),
                       ("measure", "strain_measure")):
            if getattr(args, opt) is not None:
                strain[k] = getattr(args, opt)
        strain = strain or True
    # read the results (and compute strain) once for every format
    frames_all, units, _ = collect_frames(data, strain=strain, units=units)

    base = _export_base(list(args.inputs), args.output)
    known = {".mat", ".csv", ".vtu", ".txt", ".png", ".gif", ".mp4", ".pdf"}
    single = len(formats) == 1 and base.suffix.lower() in known
    if base.suffix.lower() in known and not single:
        base = base.with_suffix("")
    ext = {"mat": ".mat", "csv": ".csv", "vtu": ".vtu", "davis": ".txt", "png": ".png",
           "gif": ".gif", "mp4": ".mp4", "pdf": ".pdf"}
    fields = args.field or ["u"]
    n = len(frames_all)
    print(f"{PROG} export: {n} frame(s) ({frames_all[0].index} to {frames_all[-1].index}); "
          f"{units.describe()}")
    failed = 0
    for fmt in formats:
        jobs = []
        if fmt in ("png", "gif", "mp4"):
            for field in fields:
                target = base if single and len(fields) == 1 else \
                    base.with_name(f"{base.name}_{field}{ext[fmt]}")
                opts = {"field": field, "frames": args.frames}
                if fmt == "png":
                    opts["dpi"] = args.dpi
                else:
                    opts["fps"] = args.fps
                jobs.append((target, opts))
        else:
            target = base if single else base.with_name(base.name + ext[fmt])
            opts = {"frames": args.frames}
            if fmt == "pdf" and args.line is not None:
                opts["line"] = tuple(args.line)
            if fmt == "vtu":
                opts["encoding"] = args.encoding
            jobs.append((target, opts))
        for target, opts in jobs:
            if fmt != "davis":
                opts["units"] = units
                opts["strain"] = strain
            try:
                out = export_result(frames_all, target, to=fmt, **opts)
            except (EncoderNotFoundError, ValueError, OSError) as exc:
                failed += 1
                msg = " ".join(str(exc).split())
                print(f"{PROG}: error: {fmt}: {msg}", file=sys.stderr)
                continue
            paths = out if isinstance(out, list) else [out]
            shown = paths if len(paths) <= 3 else [paths[0], f"... ({len(paths)} files)",
                                                    paths[-1]]
            for p in shown:
                print(f"  {fmt}: {p.resolve() if isinstance(p, Path) else p}")
    return 2 if failed else 0


if __name__ == "__main__":  # python -m napari_aldic.cli
    sys.exit(main())
