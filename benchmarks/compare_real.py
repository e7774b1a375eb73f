"""Agreement with pyALDIC on the real open-hole tension pair, side by side.

Usage::

    python benchmarks/compare_real.py --pyaldic /work/pyaldic-venv/bin/python

Runs napari-aldic (Local DIC; AL-DIC with its defaults; AL-DIC as plain
Algorithm 1: ``smooth=0, second_order_warp=False``) and pyALDIC's AL-DIC
(GUI defaults, through ``pyaldic_runner.py``) on ``sample_data/open_hole_tension``
with the sample ROI (hole and background excluded), subset 31, step 8. Our
fields are interpolated linearly at pyALDIC's valid nodes (inside our mesh);
the script prints mean, standard deviation and 99th percentile of the
differences, and the same between our own variants. There is no ground truth
for real images: agreement within the noise and no systematic offset is the
check.
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pyaldic", help="python of a venv with al-dic installed")
    args = ap.parse_args()

    from napari_aldic.engine import correlate

    folder, ref, dfm, roi = _load()
    runs = {}
    for name, kw in (("local", dict(method="local")),
                     ("aldic", dict(method="aldic")),
                     ("aldic_plain", dict(method="aldic", smooth=0.0, second_order_warp=False))):
        correlate(ref, dfm, roi=roi, **kw)  # JIT warm-up
        t = time.perf_counter()
        res = correlate(ref, dfm, roi=roi, **kw)
        runs[name] = res
        extra = res.meta.get("regularisation", {})
        print(f"{name:12s} {time.perf_counter() - t:.2f} s, {res.x.size} POI, "
              f"{int(res.valid.sum())} valid, smooth {extra.get('smooth_px', '-')} px",
              flush=True)
    report = {}
    a = runs["aldic"]
    for other in ("local", "aldic_plain"):
        b = runs[other]
        both = a.valid & b.valid
        report[f"aldic-vs-{other}"] = _stats(a.u[both] - b.u[both], a.v[both] - b.v[both])
    if args.pyaldic:
        with tempfile.TemporaryDirectory() as tmp:
            mask = Path(tmp) / "mask.npy"
            np.save(mask, roi)
            out = Path(tmp) / "pyaldic.npz"
            cmd = [args.pyaldic, str(HERE / "pyaldic_runner.py"),
                   str(folder / "oht_cfrp_00.tiff"), str(folder / "oht_cfrp_11.tiff"),
                   "--subset", "31", "--step", "8", "--method", "aldic", "--mask", str(mask),
                   "--repeat", "1", "--out", str(out)]
            line = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
            print("pyALDIC", line.strip().splitlines()[-1], flush=True)
            p = np.load(out)
            ok = np.isfinite(p["u"]) & np.isfinite(p["v"])
            px, py, pu, pv = p["x"][ok], p["y"][ok], p["u"][ok], p["v"][ok]
        for name, res in runs.items():
            u, v = _interp(res, px, py)
            report[f"{name}-vs-pyaldic"] = _stats(u - pu, v - pv)
    for k, s in report.items():
        print(f"{k:22s} n={s['n']:5d} mean=({s['mean_du']:+.4f}, {s['mean_dv']:+.4f}) "
              f"std=({s['std_du']:.4f}, {s['std_dv']:.4f}) p99|d|={s['p99_abs']:.4f} px")
    print(json.dumps(report))


if __name__ == "__main__":
    sys.exit(main())
