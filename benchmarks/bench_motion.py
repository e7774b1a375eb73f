"""Large motion versus small motion: points of interest per second side by side.

Usage::

    python benchmarks/bench_motion.py                         # 1024, 4096, 10000
    python benchmarks/bench_motion.py --sizes 1024 4096 --repeat 3
    python benchmarks/bench_motion.py --sizes 1024 --methods local --no-anchors

For every size N two synthetic 8-bit speckle pairs (exact truth, 2 grey
levels of noise) are correlated with subset 31, step 8 and the default FFT
initial guess:

* ``small``: 0.2 % / -0.1 % strain, 0.2 degree rotation, (0.37, -0.61) px;
* ``large``: 1 % / -0.3 % strain and a 0.5 degree rotation about the image
  centre plus a (20.3, -18.7) px translation, as in a tensile test; the
  motion varies by 0.01 N px across the image (100 px at 10k).

The runs are interleaved (small, large, small, large, ...) in one process,
after a JIT warm-up, so the ratio of their POI/s is measured under the same
load (the machine is shared); each time is the minimum of ``--repeat`` runs.
``--no-anchors`` adds a third column, the large pair with
``anchor_spacing=0`` (coarse nodes searched around zero motion, the guess
before anchors), in the same run. Reported per case: seconds, POI/s (also
without the ``quality`` stage, the per-node speckle-quality and uncertainty
maps, which cost the same for any motion), the stage times and diagnostics
of ``meta["timing"]`` (``anchors`` matched, ``rescue_nodes`` retried by the
repair stage, ``rescue_searches`` searched on their own), valid nodes, RMSE
and the number of valid nodes off by more than 0.5 px ("wrong"). Pairs are
cached in ``benchmarks/_cache/`` (not tracked).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CACHE = HERE / "_cache"
WRONG_PX = 0.5


def field(kind: str, n: int):
    from napari_aldic.engine import synthetic as S

    c = (n / 2, n / 2)
    if kind == "small":
        return S.Affine.strain_rotation(exx=0.002, eyy=-0.001, angle_deg=0.2, center=c,
                                        t=(0.37, -0.61))
    return S.Affine.strain_rotation(exx=0.01, eyy=-0.003, angle_deg=0.5, center=c,
                                    t=(20.3, -18.7))


def pair(kind: str, n: int):
    """Cached ``(reference, deformed)`` uint8 pair."""
    from napari_aldic.engine import synthetic as S

    CACHE.mkdir(exist_ok=True)
    path = CACHE / f"motion_{kind}_{n}.npz"
    if not path.exists():
        t = time.perf_counter()
        # n_quad=1 keeps 10k^2 generation to minutes; margin beyond the largest motion
        ref, dfm = S.speckle_pair((n, n), field(kind, n), noise=2.0, seed=n, n_quad=1,
                                  margin=0.012 * n + 40)
        np.savez(path, ref=ref, dfm=dfm)
        print(f"  generated {kind} {n}^2 pair in {time.perf_counter() - t:.0f} s", flush=True)
    z = np.load(path)
    return z["ref"], z["dfm"]


def run_once(kind: str, n: int, ref, dfm, method: str, **kw) -> dict:
    from napari_aldic.engine import correlate

    t = time.perf_counter()
    res = correlate(ref, dfm, subset=31, step=8, method=method, **kw)
    sec = time.perf_counter() - t
    ut, vt = field(kind, n).displacement(res.x, res.y)
    v = res.valid
    err = np.hypot(res.u - ut, res.v - vt)
    return {"seconds": sec, "n_poi": len(res), "valid": int(v.sum()),
            "rmse_px": float(np.sqrt(np.mean(err[v] ** 2))) if v.any() else float("nan"),
            "wrong": int((v & ~(err <= WRONG_PX)).sum()),
            "timing": {k: round(float(s), 3) for k, s in res.meta["timing"].items()}}


def bench_size(n: int, methods, repeat: int, no_anchors: bool) -> list[dict]:
    from napari_aldic.engine import correlate

    imgs = {k: pair(k, n) for k in ("small", "large")}
    cases = [("small", "small", {}), ("large", "large", {})]
    if no_anchors:
        cases.append(("large, anchors off", "large", {"anchor_spacing": 0}))
    rows = []
    for method in methods:
        r0, d0 = imgs["small"]
        correlate(r0[:256, :256], d0[:256, :256], method=method)  # JIT warm-up
        best: dict[str, dict] = {}
        for _ in range(repeat):
            for name, kind, kw in cases:
                r = run_once(kind, n, *imgs[kind], method, **kw)
                if name not in best or r["seconds"] < best[name]["seconds"]:
                    best[name] = r
        small = best["small"]["n_poi"] / best["small"]["seconds"]
        small_dic = best["small"]["n_poi"] / _dic_seconds(best["small"])
        for name, _, _ in cases:
            r = best[name]
            r.update(size=n, method=method, case=name, poi_per_s=r["n_poi"] / r["seconds"])
            r["ratio_to_small"] = r["poi_per_s"] / small
            r["dic_poi_per_s"] = r["n_poi"] / _dic_seconds(r)
            r["dic_ratio_to_small"] = r["dic_poi_per_s"] / small_dic
            rows.append(r)
            _print(r)
    return rows


def _dic_seconds(r: dict) -> float:
    """Seconds without the speckle-quality stage (SSSIG and uncertainty maps,
    the same work whatever the motion)."""
    return r["seconds"] - r["timing"].get("quality", 0.0)


def _print(r: dict) -> None:
    t = r["timing"]
    stages = " ".join(f"{k}={t.get(k, 0):.2f}" for k in ("prefilter", "init", "icgn", "rescue"))
    diag = " ".join(f"{k}={int(t.get(k, 0))}" for k in ("anchors", "rescue_nodes",
                                                         "rescue_searches"))
    print(f"{r['size']:6d} {r['method']:6s} {r['case']:19s} {r['seconds']:7.2f} s "
          f"{r['poi_per_s']:8.0f} POI/s  x{r['ratio_to_small']:.2f} (without quality "
          f"{r['dic_poi_per_s']:.0f} POI/s x{r['dic_ratio_to_small']:.2f})  valid {r['valid']}/"
          f"{r['n_poi']} wrong {r['wrong']} rmse {r['rmse_px']:.4f}  [{stages}] [{diag}]",
          flush=True)


def main(argv=None) -> None:
    import numba
    import scipy

    from napari_aldic.engine.core.version import __version__

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096, 10000])
    ap.add_argument("--methods", nargs="+", default=["local", "aldic"],
                    choices=["local", "aldic"])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--no-anchors", action="store_true",
                    help="also run the large pair with anchor_spacing=0")
    ap.add_argument("--json", type=Path, help="write the rows here")
    args = ap.parse_args(argv)
    print(f"napari-aldic {__version__}, numpy {np.__version__}, scipy {scipy.__version__}, "
          f"numba {numba.__version__} ({numba.get_num_threads()} threads), "
          f"{platform.processor() or platform.machine()}", flush=True)
    rows = []
    for n in args.sizes:
        rows += bench_size(n, args.methods, args.repeat, args.no_anchors)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
