"""Throughput and memory of Local DIC and AL-DIC, optionally beside pyALDIC.

Usage::

    python benchmarks/bench_dic.py                      # napari-aldic only
    python benchmarks/bench_dic.py --pyaldic /work/pyaldic-venv/bin/python
    python benchmarks/bench_dic.py --methods local aldic --sizes 256 512 1024 2048 \
        --rss 1024 4096

For every size N the same synthetic 8-bit speckle pair (analytic truth: 0.2 %
uniform strain, 0.2 degree rotation and a sub-pixel translation, plus 2 grey
levels of noise) is correlated with subset 31, step 8, FFT initial guess.
Times are the median of ``--repeat`` runs after a JIT warm-up, in points of
interest (nodes) per second; the RMSE against the truth is over valid nodes.
Peak resident memory is measured in a fresh subprocess per case
(``ru_maxrss``: the whole process, interpreter, imports and the two images
included; the RSS before the call is reported too). With ``--pyaldic`` the
reference program runs on the very same images in the same benchmark run
(see ``benchmarks/pyaldic_runner.py``), so speed ratios are like for like.
Images are cached in ``benchmarks/_cache/`` (not tracked).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CACHE = HERE / "_cache"


def field_for(n: int):
    from napari_aldic.engine import synthetic as S

    return S.Affine.strain_rotation(exx=0.002, eyy=-0.001, angle_deg=0.2,
                                    center=(n / 2, n / 2), t=(0.37, -0.61))


def pair_path(n: int) -> Path:
    """Cached ``.npz`` with ``ref``/``dfm`` (uint8) for size ``n``."""
    from napari_aldic.engine import synthetic as S

    CACHE.mkdir(exist_ok=True)
    p = CACHE / f"pair_{n}.npz"
    if not p.exists():
        t = time.perf_counter()
        ref, dfm = S.speckle_pair((n, n), field_for(n), noise=2.0, seed=n,
                                  n_quad=3 if n > 2048 else 4)
        np.savez(p, ref=ref, dfm=dfm)
        print(f"  generated {n}x{n} pair in {time.perf_counter() - t:.1f} s", flush=True)
    return p


def tiff_paths(n: int) -> tuple[Path, Path]:
    import tifffile

    r, d = CACHE / f"ref_{n}.tif", CACHE / f"dfm_{n}.tif"
    if not r.exists() or not d.exists():
        z = np.load(pair_path(n))
        tifffile.imwrite(r, z["ref"], photometric="minisblack")
        tifffile.imwrite(d, z["dfm"], photometric="minisblack")
    return r, d


def time_ours(n: int, repeat: int, method: str = "local", **kw) -> dict:
    from napari_aldic.engine import correlate

    z = np.load(pair_path(n))
    ref, dfm = z["ref"], z["dfm"]
    correlate(ref[:256, :256], dfm[:256, :256], method=method)  # JIT warm-up
    secs, res = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        res = correlate(ref, dfm, subset=31, step=8, method=method, **kw)
        secs.append(time.perf_counter() - t)
    ut, vt = field_for(n).displacement(res.x, res.y)
    v = res.valid
    rmse = float(np.sqrt(np.mean((res.u[v] - ut[v]) ** 2 + (res.v[v] - vt[v]) ** 2)))
    med = float(np.median(secs))
    stages = {k: round(s, 4) for k, s in res.meta["timing"].items()}
    return {"n_poi": len(res), "n_valid": int(v.sum()), "median_s": med,
            "poi_per_s": len(res) / med, "rmse_px": rmse, "seconds": secs,
            "stages_last_run": stages}


# Peak RSS is read from VmHWM (reset at exec), not ru_maxrss, which Linux
# carries over from the forking parent and would report the benchmark's own size.
_RSS_CHILD = r"""
import json, sys, time
import numpy as np
from napari_aldic.engine import correlate
def hwm():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
z = np.load(sys.argv[1]); ref, dfm = z["ref"], z["dfm"]
search = int(sys.argv[2]); method = sys.argv[3]
base = hwm()
t = time.perf_counter()
res = correlate(ref, dfm, subset=31, step=8, search=search, method=method)
el = time.perf_counter() - t
print(json.dumps({"n_poi": len(res), "n_valid": int(res.valid.sum()), "seconds": el,
                  "rss_before_mb": base, "peak_rss_mb": hwm()}))
"""


def rss_ours(n: int, search: int, method: str = "local") -> dict:
    path = pair_path(n)
    out = subprocess.run([sys.executable, "-c", _RSS_CHILD, str(path), str(search), method],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def run_pyaldic(python: str, n: int, repeat: int, method: str = "local") -> dict:
    r, d = tiff_paths(n)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "res.npz"
        cmd = [python, str(HERE / "pyaldic_runner.py"), str(r), str(d), "--subset", "31",
               "--step", "8", "--method", method, "--repeat", str(repeat), "--out", str(out)]
        proc = subprocess.run(cmd, capture_output=True, text=True,
                              env={**os.environ, "QT_QPA_PLATFORM": "offscreen"})
        if proc.returncode != 0:
            return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr else "failed"}
        summary = json.loads(proc.stdout.strip().splitlines()[-1])
        z = np.load(out)
        ut, vt = field_for(n).displacement(z["x"], z["y"])
        ok = np.isfinite(z["u"]) & np.isfinite(z["v"])
        summary["rmse_px"] = float(np.sqrt(np.mean((z["u"][ok] - ut[ok]) ** 2
                                                   + (z["v"][ok] - vt[ok]) ** 2)))
    return summary


def _throughput_row(n: int, method: str, args) -> dict:
    """One case: ``args.rounds`` rounds of ours then pyALDIC (alternated, so a
    drift of the shared machine hits both), each the median of ``args.repeat``
    runs; the row keeps the last round's figures, every round's POI/s and the
    ratio of each round."""
    rounds = []
    for _ in range(max(1, args.rounds)):
        row = {"size": n, "method": method, "ours": time_ours(n, args.repeat, method)}
        if args.pyaldic:
            row["pyaldic"] = run_pyaldic(args.pyaldic, n, args.repeat, method)
            if "poi_per_s" in row["pyaldic"]:
                row["ratio"] = row["ours"]["poi_per_s"] / row["pyaldic"]["poi_per_s"]
        rounds.append(row)
    row = rounds[-1]
    row["rounds"] = [{"ours_poi_per_s": r["ours"]["poi_per_s"],
                      "pyaldic_poi_per_s": r.get("pyaldic", {}).get("poi_per_s"),
                      "ratio": r.get("ratio"), "load": os.getloadavg()[0]} for r in rounds]
    return row


def _print_row(row: dict) -> None:
    o, method, n = row["ours"], row["method"], row["size"]
    line = (f"{method:5s} {n:5d}^2  ours {o['poi_per_s']:9,.0f} POI/s ({o['n_poi']} POI,"
            f" median {o['median_s']:.3f} s, RMSE {o['rmse_px']:.4f} px)")
    if "pyaldic" in row and "poi_per_s" in row["pyaldic"]:
        p = row["pyaldic"]
        line += (f" | pyALDIC {p['poi_per_s']:8,.0f} POI/s (RMSE {p['rmse_px']:.4f} px)"
                 f" | x{row['ratio']:.2f}")
    print(line, flush=True)
    print("      stages (s, last run):", o["stages_last_run"], flush=True)
    if len(row["rounds"]) > 1:
        ours = [r["ours_poi_per_s"] for r in row["rounds"]]
        line = (f"      {len(ours)} rounds: ours POI/s median {np.median(ours):,.0f}, "
                f"best {max(ours):,.0f}")
        ratios = [r["ratio"] for r in row["rounds"] if r["ratio"] is not None]
        if ratios:
            py = [r["pyaldic_poi_per_s"] for r in row["rounds"] if r["ratio"] is not None]
            line += (f"; pyALDIC median {np.median(py):,.0f}, best {max(py):,.0f}; ratio per "
                     f"round {', '.join(f'{r:.2f}' for r in ratios)} (median "
                     f"{np.median(ratios):.2f}, best rounds {max(ours) / max(py):.2f})")
        print(line, flush=True)


def machine() -> dict:
    import numba
    import scipy

    import napari_aldic

    return {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
            "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "numba": numba.__version__,
            "napari_aldic": napari_aldic.__version__,
            "numba_threads": numba.get_num_threads()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[256, 512, 1024, 2048])
    ap.add_argument("--rss", type=int, nargs="*", default=[1024, 4096],
                    help="sizes for the peak-RSS runs (fresh subprocess each)")
    ap.add_argument("--rss-search", type=int, default=64,
                    help="NCC search half-range (px) for the RSS runs")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--rounds", type=int, default=1,
                    help="alternate ours and pyALDIC this many times per case (each round "
                         "times --repeat runs of each); POI/s and ratios: median and best round")
    ap.add_argument("--methods", nargs="+", default=["local", "aldic"],
                    choices=["local", "aldic"])
    ap.add_argument("--pyaldic", metavar="PYTHON",
                    help="python of a venv with al-dic installed, to run pyALDIC too")
    ap.add_argument("--json", type=Path, help="write all figures to this file")
    args = ap.parse_args(argv)

    report = {"machine": machine(), "date": time.strftime("%Y-%m-%d %H:%M"),
              "params": {"subset": 31, "step": 8}, "throughput": [], "rss": []}
    print(json.dumps(report["machine"]))
    for method in args.methods:
        for n in args.sizes:
            row = _throughput_row(n, method, args)
            report["throughput"].append(row)
            _print_row(row)
    for method in args.methods:
        for n in args.rss:
            row = {"size": n, "method": method, "search": args.rss_search,
                   "ours": rss_ours(n, args.rss_search, method)}
            o = row["ours"]
            line = (f"{method:5s} {n:5d}^2 RSS ours peak {o['peak_rss_mb']:7.0f} MB (before call "
                    f"{o['rss_before_mb']:.0f} MB, {o['seconds']:.2f} s, {o['n_poi']} POI, "
                    f"search {args.rss_search} px)")
            if args.pyaldic and n <= 2048:
                p = run_pyaldic(args.pyaldic, n, 1, method)
                row["pyaldic"] = p
                if "peak_rss_mb" in p:
                    line += f" | pyALDIC peak {p['peak_rss_mb']:.0f} MB"
            report["rss"].append(row)
            print(line, flush=True)
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
