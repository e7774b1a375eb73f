"""The argument parser of ``napari-aldic``: one function per command, one per
group of shared options."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import __version__
from ..engine import DICParams, StrainParams
from ..engine.synthetic import CASES
from ..i18n import tr, tr_noop
from .console import PROG

#: run/params options that override fields of the parameter file (dest = DICParams field)
OVERRIDES = ("subset", "step", "search", "search_max", "method", "interpolation", "n_threads",
             "smooth", "second_order_warp", "shape_function")
EXPORT_FORMATS = ("mat", "csv", "vtu", "davis", "png", "gif", "mp4", "pdf")
REFERENCE_MODES = ("accumulative", "incremental")
#: help line and description of every command
TEXTS = {
    "demo": (
        tr_noop("analyse a synthetic speckle pair with exact truth"),
        tr_noop("Render a synthetic speckle pair with a known displacement field, "
                "correlate it, report the error against the truth and write the "
                "images, the result and a figure into a folder.")),
    "run": (
        tr_noop("analyse an image pair, a TIFF stack or a folder of images"),
        tr_noop("Correlate images against a reference. INPUT is either REF DEF "
                "[DEF ...] (one image per file), or one multi-page TIFF stack or one "
                "folder of images (natural sort order); frame 0 is the reference. A "
                "stack writes a run folder (the format of track), resumed by rerunning.")),
    "params": (
        tr_noop("write a parameter file (defaults, a file, and options)"),
        tr_noop("Write the analysis settings as readable JSON: the defaults, or "
                "--params FILE, with the options below applied. Use the file with "
                "'napari-aldic run --params FILE', 'export --settings FILE' or the "
                "napari widget's 'Load parameters'.")),
    "export": (
        tr_noop("export results to MAT, CSV, VTU, DaVis text, PNG, GIF, MP4, PDF"),
        tr_noop("Export results: one result .npz, several, a .mat written by "
                "export, or a run folder (written by 'run -o FOLDER' or track). "
                "Outputs are named OUT.<ext> (images OUT_<field>.png, one per frame "
                "for a sequence: OUT_<field>_frame#####.png). See docs/exports.md.")),
    "probe": (
        tr_noop("line gauges, crack opening, points, areas and stress over the frames"),
        tr_noop("Measure probes at every frame of RUN (a run folder or a result file), in "
                "reference-image pixels: line gauges (strain, true strain, elongation, crack "
                "opening/sliding), points and areas; with --load, the testing machine's load "
                "and the engineering stress. Writes one CSV row per frame (and OUT.json: units "
                "and probes). See docs/probes.md.")),
    "advise": (
        tr_noop("the smallest subset that meets a displacement-noise target"),
        tr_noop("Predict the displacement noise of each subset size from the reference "
                "image alone (its speckle gradients, SSSIG, and its noise) and recommend the "
                "smallest subset at which most nodes meet the target. See docs/method.md, "
                "'Measurement quality and uncertainty'.")),
    "noise-floor": (
        tr_noop("displacement and strain noise of a static pair"),
        tr_noop("Correlate two images of the unloaded, unmoved specimen with the settings "
                "of the measurement; the scatter of u, v (about a fitted rigid motion) and "
                "of the strains is the noise floor to report with the results (iDICs Good "
                "Practices Guide).")),
    # issue 27: HRDIC in the SEM
    "sem-calibrate": (
        tr_noop("calibrate the SEM's spatial distortion from translated images"),
        tr_noop("Fit the time-invariant distortion of the SEM image field from images of "
                "one undeformed area after rigid stage translations of unknown amount (up "
                "to about a tenth of the field of view, along x and y; T0 is the "
                "reference). Use the file with 'napari-aldic run --distortion FILE'. See "
                "docs/sem.md.")),
    "sem-drift": (
        tr_noop("calibrate the SEM beam drift from a time series of images"),
        tr_noop("Fit the beam drift, a smooth function of scan time, from images of the "
                "undeformed, unmoved area taken one after the other (image 0 is the "
                "reference); the scan timing comes from the FEI/Zeiss metadata or "
                "--dwell/--line-time. Use the file with 'napari-aldic run --drift FILE'. "
                "See docs/sem.md.")),
    "watch": (
        tr_noop("live DIC: analyse frames as a camera writes them into a folder"),
        tr_noop("Watch FOLDER and correlate every frame file once it is complete (the first "
                "one, in natural order, is the reference) into the run folder RUN_DIR, the "
                "format of 'run' (rerun the same command to resume). Prints one line per "
                "frame; with --probes, a probe CSV grows a row per frame. Ends after "
                "--idle-timeout seconds without a new frame, or on Ctrl+C. See "
                "docs/live.md.")),
}


class _Formatter(argparse.HelpFormatter):
    """argparse's help layout with the translated "usage:" heading."""

    def add_usage(self, usage, actions, groups, prefix=None):
        return super().add_usage(usage, actions, groups,
                                 tr("usage:") + " " if prefix is None else prefix)


def _translate_headings(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """argparse's own texts in the help (its titles and the -h line) through ``tr``."""
    parser._positionals.title = tr("positional arguments")
    parser._optionals.title = tr("options")
    for action in parser._actions:
        if action.option_strings == ["-h", "--help"]:
            action.help = tr("show this help message and exit")
    return parser


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``napari-aldic``."""
    parser = _translate_headings(argparse.ArgumentParser(
        prog=PROG, description=tr("2-D digital image correlation (napari-aldic engine)."),
        formatter_class=_Formatter))
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}",
                        help=tr("show the program's version number and exit"))
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    add_demo(sub)
    add_run(sub)
    add_params(sub)
    add_export(sub)
    add_probe(sub)
    add_advise(sub)
    add_noise_floor(sub)
    add_sem_calibrate(sub)
    add_sem_drift(sub)
    add_watch(sub)
    return parser


# ----------------------------------------------------------------- commands
def _command(sub, name: str) -> argparse.ArgumentParser:
    """The parser of command ``name`` (texts from ``TEXTS``)."""
    help_line, description = TEXTS[name]
    cmd = _translate_headings(sub.add_parser(name, help=tr(help_line),
                                             description=tr(description),
                                             formatter_class=_Formatter))
    add_log_options(cmd)
    return cmd


def add_log_options(p: argparse.ArgumentParser) -> None:
    """``--quiet`` / ``--verbose`` of every command (cli/console.py ``setup_logging``)."""
    p.add_argument("-q", "--quiet", action="store_true",
                   help=tr("print only warnings and errors (no summaries, no progress)"))
    p.add_argument("-v", "--verbose", action="count", default=0,
                   help=tr("log one greppable line per frame to stderr (frame, seconds, "
                           "compile seconds, trusted fraction); -vv adds debug lines"))


def add_demo(sub) -> None:
    demo = _command(sub, "demo")
    demo.add_argument("--out", type=Path, default=Path("aldic_demo"),
                      help=tr("output folder (default: ./aldic_demo)"))
    demo.add_argument("--size", type=int, default=512,
                      help=tr("image size N for N x N (default 512)"))
    demo.add_argument("--noise", type=float, default=1.0, metavar="GL",
                      help=tr("Gaussian noise std in grey levels, 8-bit images (default 1)"))
    demo.add_argument("--field", choices=CASES, default=CASES[0],
                      help=tr("displacement field (default: strain = 1%% strain + 0.5 deg "
                              "rotation + sub-pixel translation)"))
    demo.add_argument("--subset", type=int, default=DICParams.subset,
                      help=tr("subset full width, px (default 31)"))
    demo.add_argument("--step", type=int, default=DICParams.step,
                      help=tr("node spacing, px (default 8)"))
    demo.add_argument("--method", choices=("local", "aldic"), default=DICParams.method)
    demo.add_argument("--seed", type=int, default=0, help=tr("speckle pattern seed (default 0)"))


def add_run(sub) -> None:
    run = _command(sub, "run")
    run.add_argument("inputs", nargs="+", type=Path, metavar="INPUT",
                     help=tr("REF DEF [DEF ...], or STACK.tif, or FOLDER"))
    run.add_argument("--roi", type=Path, metavar="MASK",
                     help=tr("ROI mask: image file (nonzero = analysed) or .npy array"))
    add_param_options(run)
    run.add_argument("-o", "--output", type=Path, metavar="OUT",
                     help=tr("a pair: OUT.npz (default ./aldic_result.npz); a stack, or a "
                          "folder given here: a run folder (sequence.json + "
                          "frame_#####.npz; OUT.npz means the folder OUT; default "
                          "./aldic_result) that the same command resumes and that is "
                          "refused when it holds another analysis"))
    run.add_argument("--plot", action="store_true",
                     help=tr("also write a PNG figure of u and v beside each result"))
    run.add_argument("--reference", choices=REFERENCE_MODES, default="accumulative",
                     help=tr("stacks: correlate every frame against frame 0 (accumulative) "
                          "or against the previous frame, composed back to frame 0 "
                          "(incremental); results always refer to frame 0"))
    run.add_argument("--scheduler", metavar="ADDRESS|threads|processes",
                     help=tr("stacks: run the frames in parallel on local threads, on local "
                          "worker processes, or on the dask cluster at ADDRESS (e.g. "
                          "tcp://head:8786; workers read their frames from the stack "
                          "themselves, see docs/cluster.md); default: one frame after the "
                          "other"))
    run.add_argument("--workers", type=int, metavar="N",
                     help=tr("with --scheduler threads or processes: N frames at a time "
                          "(default: the CPU count)"))
    run.add_argument("--tile-size", type=int, metavar="N", dest="tile_size",
                     help=tr("a pair: correlate in blocks of N x N pixels, reading the images "
                             "tile by tile (for images larger than memory); 0 never tiles; "
                             "default: tiles pairs over 40 million pixels, blocks of 2048"))
    run.add_argument("--tile-workers", type=int, metavar="N", dest="tile_workers",
                     help=tr("with tiling: N blocks correlated at once (default 1)"))
    run.add_argument("--channel", type=int, metavar="N",
                     help=tr("a hyperstack (TIFF or OME-Zarr with a channel axis): analyse "
                             "channel N (from 0)"))
    run.add_argument("--progress", choices=("auto", "bar", "json", "none"), default="auto",
                     help=tr("stacks: a progress bar on a terminal, JSON lines on stderr "
                             "otherwise (auto), or as chosen"))
    run.add_argument("--params-out", type=Path, metavar="FILE.json", dest="params_out",
                     help=tr("also write the complete parameters used (file and options "
                          "merged) to FILE.json, for --params of a later run"))
    add_unit_options(run)
    add_sem_options(run)
    run.add_argument("--volume", action="store_true",
                     help=tr("the inputs are volumes: a 3-D TIFF is one volume (z, y, x), a "
                             "4-D TIFF or a folder a sequence of volumes (digital volume "
                             "correlation; without it a 3-D TIFF is a stack of 2-D frames)"))
    run.add_argument("--block", type=int, metavar="N",
                     help=tr("with --volume: read and solve the volumes in blocks of about N "
                             "voxels a side, never loading them whole (tiled TIFFs, zarr "
                             "folders or .npy files, one volume each)"))


def add_params(sub) -> None:
    prm = _command(sub, "params")
    prm.add_argument("output", type=Path, metavar="OUT.json", help=tr("file to write"))
    add_param_options(prm)
    add_unit_options(prm)
    add_strain_options(prm)
    prm.add_argument("--reference", choices=REFERENCE_MODES,
                     help=tr("tracking of stacks (the 'tracking' section; see 'run --reference')"))


def add_export(sub) -> None:
    exp = _command(sub, "export")
    exp.add_argument("inputs", nargs="+", type=Path, metavar="INPUT",
                     help=tr("RESULT.npz [RESULT.npz ...], RESULT.mat or RUN_FOLDER"))
    exp.add_argument("--to", nargs="+", required=True, metavar="FORMAT", dest="formats",
                     help=tr("one or more of: {join} (comma or space separated)").format(
                                 join=', '.join(EXPORT_FORMATS)))
    exp.add_argument("-o", "--output", type=Path, metavar="OUT",
                     help=tr("output name without extension, or a folder (default: "
                          "RUN_FOLDER/export or RESULT without .npz)"))
    exp.add_argument("--field", nargs="+", default=None, metavar="FIELD",
                     help=tr("field(s) drawn in png/gif/mp4 (default u): u, v, magnitude, "
                          "exx, eyy, exy, e1, e2, max_shear, von_mises, rotation, zncc, "
                          "vx, vy, exx_rate, eyy_rate, exy_rate"))
    exp.add_argument("--frames", nargs="+", type=int, metavar="K",
                     help=tr("frame numbers to export (default all; the report picks up to 4)"))
    exp.add_argument("--line", nargs=4, type=float, metavar=("X0", "Y0", "X1", "Y1"),
                     help=tr("profile line for the PDF report, in pixels"))
    add_unit_options(exp)
    exp.add_argument("--settings", type=Path, metavar="FILE.json",
                     help=tr("take units and strain settings from a parameter file"))
    exp.add_argument("--no-strain", action="store_true", dest="no_strain",
                     help=tr("do not compute strain"))
    add_strain_options(exp)
    exp.add_argument("--fps", type=float, default=4.0, help=tr("GIF/MP4 frames per second"))
    exp.add_argument("--encoding", choices=("binary", "ascii"), default="binary",
                     help=tr("VTU data encoding (default binary = base64)"))
    exp.add_argument("--dpi", type=int, default=150, help=tr("PNG resolution (default 150)"))


def add_probe(sub) -> None:
    prb = _command(sub, "probe")
    prb.add_argument("run", type=Path, metavar="RUN", help=tr("run folder or result file"))
    xy = {"type": float, "action": "append"}
    prb.add_argument("--line", nargs=4, metavar=("X0", "Y0", "X1", "Y1"), **xy,
                     help=tr("line gauge between two points, px (repeat for more)"))
    prb.add_argument("--point", nargs=2, metavar=("X", "Y"), **xy, help=tr("point probe, px"))
    prb.add_argument("--area", nargs=4, metavar=("X0", "Y0", "X1", "Y1"), **xy,
                     help=tr("rectangular area probe, px"))
    prb.add_argument("--circle", nargs=3, metavar=("CX", "CY", "R"), **xy,
                     help=tr("circular area probe, px"))
    prb.add_argument("--probes", type=Path, metavar="FILE.json",
                     help=tr("probes from a file (e.g. the OUT.json of an earlier probe run)"))
    prb.add_argument("--field", nargs="+", dest="fields", metavar="FIELD",
                     help=tr("fields of point and area probes (default u v exx eyy exy)"))
    prb.add_argument("--load", type=Path, metavar="LOAD.csv", help=tr("testing-machine CSV"))
    add_load_sync_options(prb)
    prb.add_argument("-o", "--output", type=Path, required=True, metavar="OUT.csv")
    prb.add_argument("--plot", nargs="+", choices=("png", "pdf"),
                     help=tr("also write the curves (and stress-strain) as OUT.png/OUT.pdf"))
    prb.add_argument("--kymograph", nargs="+", metavar="FIELD",
                     help=tr("also write FIELD along each line at every frame "
                          "(OUT_line<i>_<FIELD>.csv)"))
    add_unit_options(prb)
    add_strain_options(prb)


# ----------------------------------------------------------------- shared options
def add_load_sync_options(p: argparse.ArgumentParser) -> None:
    """How a testing-machine load file is read and matched to the frames
    (``probe`` and ``watch``)."""
    p.add_argument("--load-column", dest="load_column", metavar="NAME",
                   help=tr("name of the load column (default: found by name)"))
    p.add_argument("--area-mm2", type=float, dest="area_mm2", metavar="A",
                   help=tr("cross-section in mm² (stress = load / A in MPa)"))
    p.add_argument("--sync", choices=("frame", "time"),
                   help=tr("match load rows to frames by a frame column, or by time = "
                           "frame / fps + offset (default: frame when the file has one)"))
    p.add_argument("--fps", type=float, metavar="F", help=tr("camera frames per second"))
    p.add_argument("--offset", type=float, default=0.0, metavar="S",
                   help=tr("time of frame 0 on the load file's clock, s (default 0)"))


def add_advise(sub) -> None:
    adv = _command(sub, "advise")
    adv.add_argument("image", type=Path, metavar="IMAGE", help=tr("reference image"))
    adv.add_argument("--roi", type=Path, metavar="MASK",
                     help=tr("ROI mask: image file (nonzero = analysed) or .npy array"))
    adv.add_argument("--target-noise", type=float, default=0.01, dest="target_noise",
                     metavar="PX", help=tr("target standard uncertainty of u and v in px "
                                           "(default 0.01)"))
    adv.add_argument("--step", type=int, help=tr("node spacing in px (default: automatic)"))
    adv.add_argument("--subsets", type=int, nargs="+", metavar="N",
                     help=tr("subset widths to try (odd; default 11 to 101)"))
    adv.add_argument("--noise", type=float, metavar="GL",
                     help=tr("image noise in grey levels (default: estimated from the image)"))
    adv.add_argument("--coverage", type=float, default=0.9,
                     help=tr("fraction of nodes that must meet the target (default 0.9)"))
    adv.add_argument("--json", type=Path, metavar="OUT.json",
                     help=tr("also write the table as JSON"))


def add_noise_floor(sub) -> None:
    nf = _command(sub, "noise-floor")
    nf.add_argument("reference", type=Path, metavar="REF", help=tr("first static image"))
    nf.add_argument("static", type=Path, metavar="STATIC",
                    help=tr("second image of the unloaded, unmoved specimen"))
    nf.add_argument("--roi", type=Path, metavar="MASK",
                    help=tr("ROI mask: image file (nonzero = analysed) or .npy array"))
    add_param_options(nf)
    nf.add_argument("--window", type=int, default=StrainParams.window,
                    help=tr("strain window in nodes (default 5)"))
    nf.add_argument("-o", "--output", type=Path, metavar="OUT.json",
                    help=tr("also write the noise floor as JSON"))


def add_unit_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--pixel-size", type=float, dest="pixel_size", metavar="S",
                   help=tr("length of one pixel in --unit (e.g. 0.05 with --unit um)"))
    p.add_argument("--unit", help=tr("length unit name (default px)"))
    p.add_argument("--frame-interval", type=float, dest="frame_interval", metavar="DT",
                   help=tr("time between frames in --time-unit (adds time, velocity and "
                        "strain-rate columns)"))
    p.add_argument("--time-unit", dest="time_unit", help=tr("time unit name (default s)"))


def add_strain_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--strain-window", type=int, dest="strain_window", metavar="N",
                   help=tr("strain window in nodes, odd >= 3 (default 5)"))
    p.add_argument("--strain-method", choices=("plane_fit", "fem"), dest="strain_method")
    p.add_argument("--strain-measure", dest="strain_measure",
                   choices=("green_lagrange", "infinitesimal", "euler_almansi"))


def add_param_options(p: argparse.ArgumentParser) -> None:
    """Options overriding fields of the parameter file (see ``OVERRIDES``)."""
    p.add_argument("--params", type=Path, metavar="FILE.json",
                   help=tr("parameter file (JSON: DICParams fields, or a file written by "
                        "'napari-aldic params' / --params-out); options below override it"))
    p.add_argument("--subset", type=int, help=tr("subset full width in px, odd (default 31)"))
    p.add_argument("--step", type=int, help=tr("node spacing in px (default 8)"))
    p.add_argument("--search", type=int, help=tr("initial search half-range in px (default 20)"))
    p.add_argument("--search-max", type=int, dest="search_max",
                   help=tr("largest search half-range in px (default: automatic)"))
    p.add_argument("--method", choices=("local", "aldic"),
                   help=tr("solver (default local, the faster one; the napari widget starts "
                        "with aldic)"))
    p.add_argument("--interpolation", choices=("auto", "cubic", "quintic"),
                   help=tr("B-spline order (default auto: quintic for very fine speckle, "
                        "else cubic; the choice is recorded in the result)"))
    p.add_argument("--shape", choices=("affine", "quadratic"), dest="shape_function",
                   help=tr("subset shape function (default affine; quadratic subsets also bend: "
                        "finer spatial resolution, about 1.9x the displacement noise at the same "
                        "subset, slower)"))
    p.add_argument("--threads", type=int, dest="n_threads", help=tr("Numba threads (default all)"))
    p.add_argument("--smooth", type=smooth_arg, metavar="auto|PX",
                   help=tr("AL-DIC thin-plate smoothing length in px; 'auto' (default) picks it "
                        "from the image noise, 0 = the paper's plain Algorithm 1"))
    p.add_argument("--affine-warp", action="store_const", const=False,
                   dest="second_order_warp",
                   help=tr("AL-DIC: never bend subsets with the global field's curvature"))


def smooth_arg(text: str):
    """``--smooth``: ``"auto"`` or a length in pixels >= 0."""
    if text == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            tr("--smooth {text!r}: give 'auto' or a length in pixels (e.g. 8)").format(
                text=text)) from None
    if not value >= 0:
        raise argparse.ArgumentTypeError(tr("--smooth {text!r}: the length must be >= 0 px").format(
                                                text=text))
    return value


# ----------------------------------------------------------------- issue 27: SEM
def add_sem_options(p: argparse.ArgumentParser) -> None:
    """``run``'s SEM corrections (docs/sem.md)."""
    p.add_argument("--distortion", type=Path, metavar="DISTORTION.json",
                   help=tr("SEM: report u, v in undistorted specimen coordinates with the "
                           "calibration written by 'sem-calibrate'"))
    p.add_argument("--scan-lines", action="store_true", dest="scan_lines",
                   help=tr("SEM: estimate and remove the x-shift of every scan line of "
                           "each image; the shifts are stored with the result and drawn "
                           "in OUT_scanlines.png"))
    p.add_argument("--drift", type=Path, metavar="DRIFT.json",
                   help=tr("SEM: remove each image's beam drift with the calibration "
                           "written by 'sem-drift'"))
    p.add_argument("--start-times", type=float, nargs="+", dest="start_times", metavar="T",
                   help=tr("with --drift: the scan start time of every input frame, s, on "
                           "the drift series' clock (default: found in the drift file when "
                           "a frame is one of its images)"))


def add_sem_calibrate(sub) -> None:
    cal = _command(sub, "sem-calibrate")
    cal.add_argument("images", nargs="+", type=Path, metavar="IMAGE",
                     help=tr("T0 T1 ...: the undeformed area, rigidly translated"))
    cal.add_argument("-o", "--output", type=Path, required=True, metavar="DISTORTION.json")
    cal.add_argument("--degree", type=int, default=4,
                     help=tr("polynomial degree of the distortion, 2 to 7 (default 4)"))
    cal.add_argument("--pixel-size", type=float, dest="pixel_size", metavar="S",
                     help=tr("length of one pixel in --unit, recorded in the file"))
    cal.add_argument("--unit", help=tr("length unit name (default px)"))
    add_param_options(cal)


def add_sem_drift(sub) -> None:
    dr = _command(sub, "sem-drift")
    dr.add_argument("images", nargs="+", type=Path, metavar="IMAGE",
                    help=tr("I0 I1 ...: the undeformed, unmoved area in scan order"))
    dr.add_argument("-o", "--output", type=Path, required=True, metavar="DRIFT.json")
    dr.add_argument("--dwell", type=float, metavar="S",
                    help=tr("dwell time per pixel, s (default: from the metadata)"))
    dr.add_argument("--line-time", type=float, dest="line_time", metavar="S",
                    help=tr("time per scan line including fly-back, s (default: from the "
                            "metadata)"))
    dr.add_argument("--start-times", type=float, nargs="+", dest="start_times", metavar="T",
                    help=tr("scan start time of every image, s (default: back to back, "
                            "t_k = k (rows x line time + --gap))"))
    dr.add_argument("--gap", type=float, default=0.0, metavar="S",
                    help=tr("pause between back-to-back images, s (default 0)"))
    dr.add_argument("--degree", type=int, default=3,
                    help=tr("polynomial degree of the drift in time (default 3)"))
    dr.add_argument("--distortion", type=Path, metavar="DISTORTION.json",
                    help=tr("correct the series for this distortion calibration first"))
    add_param_options(dr)
def add_watch(sub) -> None:
    """``napari-aldic watch`` (issue 26)."""
    w = _command(sub, "watch")
    w.add_argument("folder", type=Path, metavar="FOLDER", help=tr("folder the camera writes into"))
    w.add_argument("-o", "--output", type=Path, metavar="RUN_DIR",
                   help=tr("run folder (sequence.json + frame_#####.npz), resumed by the same "
                           "command"))
    w.add_argument("--pattern", metavar="GLOB",
                   help=tr("frame file names, e.g. 'img_*.tif' (default: every image file)"))
    w.add_argument("--roi", type=Path, metavar="MASK",
                   help=tr("ROI mask: image file (nonzero = analysed) or .npy array"))
    add_param_options(w)
    w.add_argument("--reference", choices=REFERENCE_MODES, default="accumulative",
                   help=tr("correlate every frame against frame 0 (accumulative) or against "
                           "the previous frame (incremental); results refer to frame 0"))
    w.add_argument("--idle-timeout", type=float, dest="idle_timeout", metavar="SECONDS",
                   help=tr("stop after SECONDS without a new frame (default: wait until "
                           "Ctrl+C)"))
    w.add_argument("--poll", type=float, default=0.05, metavar="SECONDS",
                   help=tr("seconds between looks at the folder (default 0.05)"))
    w.add_argument("--settle", type=float, default=0.25, metavar="SECONDS",
                   help=tr("a frame file counts as complete when it decodes and its size and "
                           "time stayed unchanged this long (default 0.25)"))
    w.add_argument("--stall", type=float, default=10.0, metavar="SECONDS",
                   help=tr("skip a file that stays unreadable this long while later frames "
                           "are complete (default 10; empty files are always waited for)"))
    w.add_argument("--max-frames", type=int, dest="max_frames", metavar="N",
                   help=tr("stop after N frames, the reference included"))
    xy = {"type": float, "action": "append"}
    w.add_argument("--probes", type=Path, metavar="FILE.json",
                   help=tr("probes from a file (as 'probe --probes'), measured at every frame"))
    w.add_argument("--line", nargs=4, metavar=("X0", "Y0", "X1", "Y1"), **xy,
                   help=tr("line gauge between two points, px (repeat for more)"))
    w.add_argument("--point", nargs=2, metavar=("X", "Y"), **xy, help=tr("point probe, px"))
    w.add_argument("--area", nargs=4, metavar=("X0", "Y0", "X1", "Y1"), **xy,
                   help=tr("rectangular area probe, px"))
    w.add_argument("--circle", nargs=3, metavar=("CX", "CY", "R"), **xy,
                   help=tr("circular area probe, px"))
    w.add_argument("--field", nargs="+", dest="fields", metavar="FIELD",
                   help=tr("fields of point and area probes (default u v exx eyy exy)"))
    w.add_argument("--probe-csv", type=Path, dest="probe_csv", metavar="OUT.csv",
                   help=tr("probe CSV, a row appended per frame (the columns of 'probe')"))
    w.add_argument("--load", type=Path, metavar="LOAD.csv",
                   help=tr("testing-machine CSV, read again as it grows"))
    add_load_sync_options(w)
    add_unit_options(w)
    add_strain_options(w)
