"""Run the reference DIC program pyALDIC on one image pair, for benchmarks.

This script drives pyALDIC (PyPI package ``al-dic``, version 1.0.3) through
its public Python API only (``al_dic.dicpara_default`` and
``al_dic.run_aldic``), so that its results and speed can be compared with
napari-aldic's own engine on the same images.  No pyALDIC code is copied here.

It MUST run in a separate virtual environment that has pyALDIC installed
(pyALDIC pulls in PySide6 and OpenCV, which napari-aldic does not want), e.g.::

    python3 -m venv /work/pyaldic-venv
    /work/pyaldic-venv/bin/pip install al-dic==1.0.3 psutil tifffile
    /work/pyaldic-venv/bin/python benchmarks/pyaldic_runner.py \\
        REF.tif DEF.tif --subset 31 --step 8 --method local --out result.npz

Usage::

    pyaldic_runner.py REF.tif DEF.tif --subset 31 --step 8 --method local|aldic
                      [--mask MASK.npy] [--repeat 3] [--no-warmup] --out result.npz

Methods:

* ``local``: pyALDIC's Local DIC -- FFT/NCC initial guess followed by the
  subset-based 6-DOF IC-GN step only (``use_global_step=False``).
* ``aldic``: the full AL-DIC pipeline -- the same local step, then the
  ADMM alternation between the local IC-GN subproblem and the global FE
  subproblem (``use_global_step=True``, default 3 ADMM iterations).

Parameter mapping:

* ``--subset`` is the FULL subset width in pixels (odd, e.g. 31).  pyALDIC's
  ``winsize`` counts the span between the outermost pixel centres, so its
  subsets are ``winsize + 1`` pixels wide (its GUI shows 41 for winsize 40);
  the runner passes ``winsize = subset - 1`` (31 -> 30).  pyALDIC requires
  ``winsize`` even, hence ``--subset`` must be odd.
* ``--step`` is the node spacing in pixels, passed as ``winstepsize``;
  pyALDIC requires a power of two.
* The ROI is the whole image, or the bounding box of ``--mask`` (a 2-D
  boolean ``.npy`` of the image shape) with the mask passed as the
  reference-frame mask (deformed frame unmasked, as pyALDIC's GUI does).
* Everything else stays at pyALDIC's GUI defaults: FFT initial guess for
  every frame with search radius 20 px and auto-expansion, accumulative
  reference, IC-GN tolerance 1e-2 / 100 iterations, 3 ADMM iterations, no
  strain computation.

Output (``--out``, npz):

* ``x``, ``y``: 1-D node coordinates in pixels, ``x`` = column index and
  ``y`` = row index, pixel centres at integers (pyALDIC's
  ``coordinates_fem``).
* ``u``, ``v``: 1-D Lagrangian displacements in pixels at those reference
  positions, ``u`` along x (columns), ``v`` along y (rows), so that the
  material point at (x, y) in REF is at (x + u, y + v) in DEF.  Nodes that
  pyALDIC could not solve are NaN.
* ``seconds`` (wall time of each timed repeat), ``n_poi`` (number of nodes),
  ``n_valid`` (nodes with finite u and v), ``peak_rss_bytes`` (process peak
  RSS from ``getrusage``), ``peak_rss_sampled_bytes`` (psutil sampling during
  the timed runs), ``baseline_rss_bytes`` (RSS just before the timed runs),
  ``subset``, ``step``, ``winsize``, ``method``.

One JSON line is printed to stdout::

    {"method", "n_poi", "median_s", "poi_per_s", "peak_rss_mb", ...}
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import resource
import sys
import threading
import time
import warnings

import numpy as np

try:
    import psutil
except ImportError:  # psutil is optional; getrusage is always there
    psutil = None

import tifffile


def _load_gray(path: str) -> np.ndarray:
    img = np.asarray(tifffile.imread(path))
    if img.ndim == 3:
        # (H, W, C) colour image -> mean of the colour channels
        if img.shape[-1] in (3, 4):
            img = img[..., :3].astype(np.float64).mean(axis=-1)
        else:
            raise SystemExit(f"{path}: expected a 2-D image, got shape {img.shape}")
    if img.ndim != 2:
        raise SystemExit(f"{path}: expected a 2-D image, got shape {img.shape}")
    return img.astype(np.float64)


def _is_pow2(n: int) -> bool:
    return n > 0 and (n & (n - 1)) == 0


def _make_para(method: str, subset: int, step: int, roi_mask: np.ndarray):
    from al_dic import dicpara_default
    from al_dic.core.data_structures import GridxyROIRange

    rows, cols = np.nonzero(roi_mask)
    if rows.size == 0:
        raise SystemExit("mask is empty")
    roi = GridxyROIRange(
        gridx=(int(cols.min()), int(cols.max())),
        gridy=(int(rows.min()), int(rows.max())),
    )
    return dicpara_default(
        winsize=subset - 1,              # full width 31 px -> winsize 30
        winstepsize=step,
        winsize_min=min(8, step),
        gridxy_roi_range=roi,
        size_of_fft_search_region=20,
        reference_mode="accumulative",
        init_guess_mode="fft",
        fft_reset_interval=0,
        fft_auto_expand_search=True,
        use_global_step=(method == "aldic"),
        admm_max_iter=3,
        show_plots=False,
    )


def _run_once(para, ref, dfm, mask):
    from al_dic import run_aldic

    ones = np.ones(ref.shape, dtype=np.uint8)
    with warnings.catch_warnings():
        # e.g. the FFT search-region auto-scale notice on small images
        warnings.simplefilter("ignore")
        return run_aldic(
            para, [ref, dfm], [mask.astype(np.uint8), ones],
            compute_strain=False,
        )


def _extract(result):
    frame = result.result_disp[0]
    U = frame.U_accum if frame.U_accum is not None else frame.U
    U = np.asarray(U, dtype=np.float64)
    xy = np.asarray(result.dic_mesh.coordinates_fem, dtype=np.float64)
    return xy[:, 0].copy(), xy[:, 1].copy(), U[0::2].copy(), U[1::2].copy()


def _watch_iterations() -> list:
    """Record the per-node IC-GN iteration counts of every Local step the
    pipeline runs (pyALDIC returns them from ``local_icgn`` but keeps them out
    of its result): the pipeline's reference to that function is wrapped, its
    outputs passed on unchanged."""
    import al_dic.core.pipeline as pipeline

    calls: list = []
    inner = pipeline.local_icgn

    def watched(*a, **k):
        out = inner(*a, **k)
        calls.append(np.asarray(out[3], dtype=np.int64).ravel())
        return out

    pipeline.local_icgn = watched
    return calls


class _RssSampler:
    """Samples the process RSS with psutil in a background thread."""

    def __init__(self, interval: float = 0.01):
        self.interval = interval
        self.peak = 0
        self._stop = threading.Event()
        self._thread = None

    def __enter__(self):
        if psutil is not None:
            self._proc = psutil.Process(os.getpid())
            self.peak = self._proc.memory_info().rss
            self._thread = threading.Thread(target=self._loop, daemon=True)
            self._thread.start()
        return self

    def _loop(self):
        while not self._stop.is_set():
            try:
                self.peak = max(self.peak, self._proc.memory_info().rss)
            except Exception:
                pass
            self._stop.wait(self.interval)

    def __exit__(self, *exc):
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self.peak = max(self.peak, self._proc.memory_info().rss)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("ref", help="reference image (TIFF)")
    ap.add_argument("deformed", help="deformed image (TIFF)")
    ap.add_argument("--subset", type=int, default=31,
                    help="full subset width in px, odd (pyALDIC winsize = subset-1)")
    ap.add_argument("--step", type=int, default=8,
                    help="node spacing in px, power of two (pyALDIC winstepsize)")
    ap.add_argument("--method", choices=("local", "aldic"), required=True)
    ap.add_argument("--mask", help="boolean ROI mask (.npy, image shape)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-warmup", action="store_true",
                    help="skip the JIT warm-up run on a small crop")
    ap.add_argument("--out", required=True, help="output .npz")
    ap.add_argument("--iterations", action="store_true",
                    help="also store the IC-GN iterations per node of the Local step "
                         "(icgn_iterations; observed by wrapping the pipeline's local_icgn)")
    args = ap.parse_args(argv)

    if args.subset < 3 or args.subset % 2 != 1:
        ap.error("--subset is the full subset width and must be odd (>= 3): "
                 "pyALDIC needs winsize = subset - 1 to be even")
    if not _is_pow2(args.step):
        ap.error("--step must be a power of two (pyALDIC requirement)")
    if args.repeat < 1:
        ap.error("--repeat must be >= 1")

    logging.basicConfig(level=logging.WARNING)
    logging.getLogger("al_dic").setLevel(logging.ERROR)

    ref = _load_gray(args.ref)
    dfm = _load_gray(args.deformed)
    if ref.shape != dfm.shape:
        raise SystemExit(f"image shapes differ: {ref.shape} vs {dfm.shape}")
    if args.mask:
        mask = np.asarray(np.load(args.mask)).astype(bool)
        if mask.shape != ref.shape:
            raise SystemExit(f"mask shape {mask.shape} != image shape {ref.shape}")
    else:
        mask = np.ones(ref.shape, dtype=bool)

    para = _make_para(args.method, args.subset, args.step, mask)

    # Warm-up: pyALDIC's kernels are Numba JIT functions (cached on disk
    # after the first compile); run the same pipeline once on a central
    # crop so compilation is not timed.  The crop must yield >= 50 nodes
    # to reach pyALDIC's batch kernels.
    warmup_s = None
    if not args.no_warmup:
        h, w = ref.shape
        c = min(h, w, max(192, args.subset + 12 * args.step))
        y0, x0 = (h - c) // 2, (w - c) // 2
        sl = (slice(y0, y0 + c), slice(x0, x0 + c))
        wmask = mask[sl] if mask[sl].any() else np.ones((c, c), dtype=bool)
        t0 = time.perf_counter()
        try:
            wpara = _make_para(args.method, args.subset, args.step, wmask)
            _run_once(wpara, ref[sl].copy(), dfm[sl].copy(), wmask)
        except Exception as exc:  # a failed warm-up must not stop the benchmark
            print(f"warning: warm-up failed: {exc!r}", file=sys.stderr)
        warmup_s = time.perf_counter() - t0

    conv = _watch_iterations() if args.iterations else None
    seconds = []
    result = None
    baseline_rss = psutil.Process(os.getpid()).memory_info().rss if psutil else 0
    with _RssSampler() as sampler:
        for _ in range(args.repeat):
            result = None  # release the previous result before the next run
            t0 = time.perf_counter()
            result = _run_once(para, ref, dfm, mask)
            seconds.append(time.perf_counter() - t0)

    x, y, u, v = _extract(result)
    # VmHWM is reset at exec; ru_maxrss is inherited from a forking parent
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # KiB on Linux
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    peak_rss = int(line.split()[1]) * 1024
    except OSError:
        pass
    n_poi = int(x.size)
    n_valid = int(np.count_nonzero(np.isfinite(u) & np.isfinite(v)))
    median_s = float(np.median(seconds))

    np.savez(
        args.out,
        x=x, y=y, u=u, v=v,
        seconds=np.asarray(seconds),
        n_poi=n_poi,
        n_valid=n_valid,
        peak_rss_bytes=int(peak_rss),
        peak_rss_sampled_bytes=int(sampler.peak),
        baseline_rss_bytes=int(baseline_rss),
        subset=args.subset,
        step=args.step,
        winsize=para.winsize,
        method=args.method,
        **({} if not conv else {"icgn_iterations": conv[-1]}),
    )

    import al_dic

    summary = {
        "method": args.method,
        "n_poi": n_poi,
        "median_s": round(median_s, 4),
        "poi_per_s": round(n_poi / median_s, 1) if median_s > 0 else None,
        "peak_rss_mb": round(peak_rss / 2**20, 1),
        "n_valid": n_valid,
        "seconds": [round(s, 4) for s in seconds],
        "warmup_s": None if warmup_s is None else round(warmup_s, 2),
        "peak_rss_sampled_mb": round(sampler.peak / 2**20, 1),
        "baseline_rss_mb": round(baseline_rss / 2**20, 1),
        "image_shape": list(ref.shape),
        "subset": args.subset,
        "winsize": int(para.winsize),
        "step": args.step,
        "al_dic": al_dic.__version__,
    }
    if conv:
        ok = np.isfinite(u) & np.isfinite(v)
        summary["median_icgn_iterations"] = float(np.median(conv[-1][ok]))
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
