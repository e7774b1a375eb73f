"""Agreement with pyALDIC on the real open-hole tension pair, side by side.

Usage::

    python benchmarks/compare_real.py --pyaldic /work/pyaldic-venv/bin/python [--subset 27 --step 8]

Runs napari-aldic (Local DIC; AL-DIC with its defaults; AL-DIC as plain
Algorithm 1: ``smooth=0, second_order_warp=False``) and pyALDIC's Local DIC
and AL-DIC (GUI defaults, through ``pyaldic_runner.py``) on
``sample_data/open_hole_tension`` with the sample ROI (hole and background
excluded), subset 27, step 8 by default (issue 22's table). For every run it
prints the time, the nodes trusted (ours: ``valid``; pyALDIC's: finite u, v)
among the interior nodes (whole subset inside the ROI) and their fraction,
and the median IC-GN iterations of the Local step (ours: ``meta["convergence"]``;
pyALDIC's: observed by the runner, ``--iterations``). Our fields are
interpolated linearly at pyALDIC's valid nodes (inside our mesh) and compared
with pyALDIC's run of the same method: mean, standard deviation and 99th
percentile of the differences, beside the trusted counts; the same between
our own variants. There is no ground truth for real images: agreement within
the noise and no systematic offset is the check.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def _load():
    import tifffile

    from napari_aldic._sample_data import OPEN_HOLE_FILES, open_hole_roi

    folder = ROOT / "sample_data" / "open_hole_tension"
    ref, dfm = (tifffile.imread(folder / name) for name in OPEN_HOLE_FILES)
    return folder, ref, dfm, open_hole_roi(ref)


def _interp(res, x, y):
    """Our u, v at points (x, y), bilinear on the node lattice (NaN outside)."""
    from scipy.interpolate import LinearNDInterpolator

    ok = res.valid
    pts = np.column_stack([res.x[ok], res.y[ok]])
    fu = LinearNDInterpolator(pts, np.column_stack([res.u[ok], res.v[ok]]))
    out = fu(np.column_stack([x, y]))
    return out[:, 0], out[:, 1]


def _stats(du, dv) -> dict:
    ok = np.isfinite(du) & np.isfinite(dv)
    d = np.hypot(du[ok], dv[ok])
    return {"n": int(ok.sum()), "mean_du": float(du[ok].mean()), "mean_dv": float(dv[ok].mean()),
            "std_du": float(du[ok].std()), "std_dv": float(dv[ok].std()),
            "p99_abs": float(np.percentile(d, 99))}


def _interior(x, y, roi: np.ndarray, subset: int) -> np.ndarray:
    """Nodes whose whole square subset lies inside ``roi`` (as tests/engine's
    real-specimen tests count them)."""
    from scipy import ndimage

    inner = ndimage.binary_erosion(roi, np.ones((subset, subset), bool), border_value=0)
    return inner[np.rint(y).astype(int), np.rint(x).astype(int)]


def _coverage(name: str, seconds: float, trusted, inside, iters) -> dict:
    """One run's line: time, trusted interior nodes, median iterations."""
    n_in = int(inside.sum())
    k = int(np.count_nonzero(trusted & inside))
    row = {"seconds": round(seconds, 3), "nodes": int(trusted.size), "trusted": int(trusted.sum()),
           "interior": n_in, "interior_trusted": k,
           "interior_trusted_fraction": round(k / max(n_in, 1), 4),
           "median_icgn_iterations": iters}
    print(f"{name:14s} {seconds:6.2f} s  trusted {row['trusted']:5d}/{row['nodes']:5d}, interior "
          f"{k:5d}/{n_in:5d} = {100 * row['interior_trusted_fraction']:5.1f} %, median "
          f"IC-GN iterations {iters}", flush=True)
    return row


def _ours(ref, dfm, roi, subset: int, step: int):
    from napari_aldic.engine import correlate

    runs, rows = {}, {}
    for name, kw in (("local", dict(method="local")),
                     ("aldic", dict(method="aldic")),
                     ("aldic_plain", dict(method="aldic", smooth=0.0, second_order_warp=False))):
        kw.update(subset=subset, step=step)
        correlate(ref, dfm, roi=roi, **kw)  # JIT warm-up
        t = time.perf_counter()
        res = correlate(ref, dfm, roi=roi, **kw)
        runs[name] = res
        conv = res.meta.get("convergence", {})
        rows[name] = _coverage(name, time.perf_counter() - t, res.valid,
                               _interior(res.x, res.y, roi, subset),
                               conv.get("median_iterations"))
    return runs, rows


def _pyaldic(python: str, folder: Path, roi, subset: int, step: int, method: str):
    """pyALDIC's field of ``method`` (finite nodes only) and its coverage row."""
    with tempfile.TemporaryDirectory() as tmp:
        mask = Path(tmp) / "mask.npy"
        np.save(mask, roi)
        out = Path(tmp) / "pyaldic.npz"
        cmd = [python, str(HERE / "pyaldic_runner.py"),
               str(folder / "oht_cfrp_00.tiff"), str(folder / "oht_cfrp_11.tiff"),
               "--subset", str(subset), "--step", str(step), "--method", method,
               "--mask", str(mask), "--repeat", "1", "--iterations", "--out", str(out)]
        line = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
        summary = json.loads(line.strip().splitlines()[-1])
        p = np.load(out)
        ok = np.isfinite(p["u"]) & np.isfinite(p["v"])
        row = _coverage(f"pyALDIC {method}", summary["median_s"], ok,
                        _interior(p["x"], p["y"], roi, subset),
                        summary.get("median_icgn_iterations"))
        return (p["x"][ok], p["y"][ok], p["u"][ok], p["v"][ok]), row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pyaldic", help="python of a venv with al-dic installed")
    ap.add_argument("--subset", type=int, default=27)
    ap.add_argument("--step", type=int, default=8)
    args = ap.parse_args()

    folder, ref, dfm, roi = _load()
    runs, coverage = _ours(ref, dfm, roi, args.subset, args.step)
    report = {}
    a = runs["aldic"]
    for other in ("local", "aldic_plain"):
        b = runs[other]
        both = a.valid & b.valid
        report[f"aldic-vs-{other}"] = _stats(a.u[both] - b.u[both], a.v[both] - b.v[both])
    if args.pyaldic:
        for method in ("local", "aldic"):
            (px, py, pu, pv), coverage[f"pyaldic_{method}"] = _pyaldic(
                args.pyaldic, folder, roi, args.subset, args.step, method)
            for name, res in runs.items():
                if name.startswith(method):
                    u, v = _interp(res, px, py)
                    report[f"{name}-vs-pyaldic_{method}"] = _stats(u - pu, v - pv)
    for k, s in report.items():
        print(f"{k:22s} n={s['n']:5d} mean=({s['mean_du']:+.4f}, {s['mean_dv']:+.4f}) "
              f"std=({s['std_du']:.4f}, {s['std_dv']:.4f}) p99|d|={s['p99_abs']:.4f} px")
    print(json.dumps({"coverage": coverage, "differences": report}))


if __name__ == "__main__":
    sys.exit(main())
