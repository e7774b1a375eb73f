"""Cost of the quality stage of ``correlate`` (speckle quality and uncertainty).

Usage::

    python benchmarks/bench_quality_cost.py [--sizes 1024 4096] [--rss 4096]
                                            [--before REV] [--repeat 2]

Local DIC (subset 31, step 8, one Numba thread) of a ``N``² uint8 pair (a
2048² synthetic speckle pattern tiled to size, the deformed image shifted by
one pixel; the quality stage does not depend on the motion). For each size,
the run with ``dic/quality.py`` as of git revision ``--before`` (default
``3be4562``, the last one before the streaming moment kernel
``kernels/moments.py``: loaded from ``git show`` and patched into
``correlate``) and with
the working tree alternate ``--repeat`` times in one process (the machine is
shared: compare the two side by side); reported: the ``"quality"`` entry of
``res.meta["timing"]`` and the total wall time, the fastest of the repeats.
``--rss``: per size, each variant correlated in its own process; reported:
peak resident memory (``ru_maxrss``) of that process. ``--values``: the
outputs of ``speckle_quality`` before and after on a 1024² pair (nodes every
8 px, affine and quadratic, with and without a ROI, plain and smoothed
steepest-descent gradients): the largest difference per field, relative to
the node's value (matrices: to the node's largest entry).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def make_pair(n: int) -> tuple[np.ndarray, np.ndarray]:
    from napari_aldic.engine.synthetic.speckle import speckle_pair

    cell, _ = speckle_pair((min(n, 2048),) * 2, noise=1.0, seed=7)
    reps = -(-n // cell.shape[0])
    f = np.tile(np.asarray(cell, np.uint8), (reps, reps))[:n, :n]
    return f, np.roll(f, 1, axis=1)


def use_before(rev: str) -> None:
    """Patch ``correlate`` to use ``dic/quality.py`` as of git ``rev``."""
    import napari_aldic.engine.dic.correlate as corr

    src = subprocess.run(["git", "show", f"{rev}:src/napari_aldic/engine/dic/quality.py"],
                         cwd=ROOT, check=True, capture_output=True, text=True).stdout
    path = Path(tempfile.mkdtemp()) / "quality_before.py"
    path.write_text(src)
    name = "napari_aldic.engine.dic._quality_before"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    corr.result_quality = mod.result_quality


def run_once(f, g) -> tuple[float, float]:
    from napari_aldic.engine import correlate

    t = time.perf_counter()
    res = correlate(f, g, subset=31, step=8, method="local", n_threads=1)
    return res.meta["timing"]["quality"], time.perf_counter() - t


def timings(n: int, rev: str, repeat: int) -> dict:
    import napari_aldic.engine.dic.correlate as corr

    after = corr.result_quality
    use_before(rev)
    before = corr.result_quality
    f, g = make_pair(n)
    best = {"before": [np.inf, np.inf], "after": [np.inf, np.inf]}
    for _ in range(repeat):
        for name, fn in (("before", before), ("after", after)):
            corr.result_quality = fn
            q, tot = run_once(f, g)
            best[name] = [min(best[name][0], q), min(best[name][1], tot)]
    corr.result_quality = after
    return {k: {"quality_s": round(v[0], 3), "total_s": round(v[1], 3)} for k, v in best.items()}


def _rel(a, b) -> float:
    fin = np.isfinite(a) & np.isfinite(b)
    axes = tuple(range(1, a.ndim))
    scale = np.max(np.abs(np.where(fin, a, 0)), axis=axes, keepdims=True) if axes else np.abs(a)
    return float(np.max(np.abs(np.where(fin, a - b, 0)) / np.where(scale > 0, scale, 1.0)))


def values(rev: str) -> dict:
    import napari_aldic.engine.dic.correlate as corr
    from napari_aldic.engine.dic import quality as new
    from napari_aldic.engine.dic.interpolation import jacobian_smoothing, steepest_descent_gradients

    use_before(rev)
    old = sys.modules["napari_aldic.engine.dic._quality_before"]
    corr.result_quality = new.result_quality
    f = make_pair(1024)[0].astype(np.float64)
    yy, xx = np.mgrid[0:1024, 0:1024]
    roi = (xx - 500) ** 2 + (yy - 530) ** 2 < 420**2
    gx, gy, _ = new._gradients(f, 3)
    j_sigma = jacobian_smoothing(f)
    jac = (*steepest_descent_gradients(f, 3, j_sigma), j_sigma)
    y, x = (a.ravel() for a in np.mgrid[0:1024:8, 0:1024:8])
    out = {}
    for shape in ("affine", "quadratic"):
        for r in (None, roi):
            for j in (None, jac):
                a, b = (m.speckle_quality(f, x, y, 31, r, shape_function=shape,
                                          gradients=(gx, gy), jacobian=j) for m in (old, new))
                key = f"{shape} roi={r is not None} smoothed_J={j is not None}"
                out[key] = {k: f"{_rel(getattr(a, k), getattr(b, k)):.1e}"
                            for k in ("mig", "sssig_x", "sssig_y", "m", "var_f", "hessian",
                                      "noise", "cross") if getattr(a, k) is not None}
                print(key, out[key], flush=True)
    return out


def rss_child(n: int, variant: str, rev: str) -> None:
    if variant == "before":
        use_before(rev)
    f, g = make_pair(n)
    q, tot = run_once(f, g)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"peak_rss_mb": round(peak), "quality_s": round(q, 2),
                      "total_s": round(tot, 2)}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="*", default=[1024, 4096])
    ap.add_argument("--rss", type=int, nargs="*", default=[4096])
    ap.add_argument("--before", default="3be4562")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--values", action="store_true")
    ap.add_argument("--child", nargs=2, metavar=("SIZE", "VARIANT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        rss_child(int(args.child[0]), args.child[1], args.before)
        return
    if args.values:
        print(json.dumps(values(args.before), indent=1))
        return
    out = {"timing": {}, "rss": {}}
    for n in args.sizes:
        out["timing"][n] = timings(n, args.before, args.repeat)
        print(n, out["timing"][n], flush=True)
    for n in args.rss:
        for variant in ("before", "after"):
            r = subprocess.run([sys.executable, __file__, "--child", str(n), variant,
                                "--before", args.before], capture_output=True, text=True,
                               check=True)
            out["rss"].setdefault(n, {})[variant] = json.loads(r.stdout.strip().splitlines()[-1])
            print(n, variant, out["rss"][n][variant], flush=True)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
