"""DVC beside al-dvc (pyALDVC 1.2.1, its CPU path), in the same run.

Each case (translation, 1 % strain, 5 degree rotation, 2 % strain + noise;
exact-truth volumes of ``engine.synthetic.volume``) is written once to a
temporary ``.npz``; every solver then runs in a fresh process of its own
(al-dvc in its own venv), warmed up first on a small volume (numba compile
and cache loading are not timed), and reports the RMSE of the displacement
at its valid nodes against the analytic truth, its valid fraction, POI/s
(nodes / seconds of the correlation call) and its peak resident memory.

    python benchmarks/bench_dvc.py [--size 128] [--aldvc /work/aldvc-venv/bin/python]

Install al-dvc in its own venv first:
``python3 -m venv /work/aldvc-venv && /work/aldvc-venv/bin/pip install al-dvc==1.2.1``.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CASES = ("translation", "strain1", "rotation5", "strain2_noise")


def _rmse(U, truth, valid):
    err = (U - truth)[valid]
    return float(np.sqrt((err ** 2).sum(1).mean())) if err.size else float("nan")


def _truth(case, xyz):
    A, t = np.asarray(case["A"]), np.asarray(case["t"])
    return xyz @ (A - np.eye(3)).T + t


def _worker_ours(method, case, subset, step):
    from napari_aldic.engine import correlate_volume
    from napari_aldic.engine.synthetic.volume import speckle_volume_pair
    a, b = speckle_volume_pair((40, 40, 40), seed=3)
    correlate_volume(a, b, subset=subset, step=step, method=method)  # warm-up
    t, c = time.perf_counter(), time.process_time()
    res = correlate_volume(case["ref"], case["dfm"], subset=subset, step=step, method=method)
    dt, cpu = time.perf_counter() - t, time.process_time() - c
    xyz = np.stack([res.x, res.y, res.z], 1)
    return xyz, np.stack([res.u, res.v, res.w], 1), res.valid, dt, cpu


def _worker_aldvc(method, case, subset, step):
    from al_dvc import dvcpara_default, run_aldvc
    win = subset - 1 if subset % 2 else subset  # al-dvc subsets are even widths
    para = dvcpara_default(winsize=win, winstepsize=step, use_global_step=method == "aldic",
                           verbose=False)
    a = np.random.default_rng(3).random((40, 40, 40)).astype(np.float32)
    run_aldvc(para, [a, np.roll(a, 1, 2)], compute_strain=False)  # warm-up
    t, c = time.perf_counter(), time.process_time()
    res = run_aldvc(para, [case["ref"], case["dfm"]], compute_strain=False)
    dt, cpu = time.perf_counter() - t, time.process_time() - c
    fr = res.result_disp[-1]
    U = np.asarray(fr.U, float)
    valid = np.isfinite(U).all(1)
    if fr.status is not None:
        valid &= np.asarray(fr.status) == 0
    if getattr(fr, "outlier", None) is not None:
        valid &= ~np.asarray(fr.outlier, bool)
    return np.asarray(res.dvc_mesh.coordinates, float), U, valid, dt, cpu


def worker(tool, method, path, subset, step):
    with np.load(path) as z:
        case = {k: z[k] for k in z.files}
    fn = _worker_ours if tool == "ours" else _worker_aldvc
    xyz, U, valid, dt, cpu = fn(method, case, subset, step)
    print(json.dumps({
        "rmse": _rmse(U, _truth(case, xyz), valid), "valid": float(valid.mean()),
        "nodes": int(len(U)), "seconds": dt, "poi_s": len(U) / dt,
        "cpu_ms_per_poi": 1e3 * cpu / len(U),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))


def _run(python, tool, method, path, subset, step):
    cmd = [python, __file__, "--worker", tool, method, str(path), "--subset", str(subset),
           "--step", str(step)]
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode:
        return {"error": out.stderr.strip().splitlines()[-1:]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--subset", type=int, default=21)
    ap.add_argument("--step", type=int, default=8)
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--methods", nargs="*", default=["local", "aldic"])
    ap.add_argument("--aldvc", default="/work/aldvc-venv/bin/python")
    ap.add_argument("--worker", nargs=3, metavar=("TOOL", "METHOD", "FILE"))
    a = ap.parse_args(argv)
    if a.worker:
        return worker(*a.worker, a.subset, a.step)
    from napari_aldic.engine.synthetic.volume import volume_case
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.cases:
            ref, dfm, motion = volume_case(name, (a.size,) * 3)
            path = Path(tmp) / f"{name}.npz"
            np.savez(path, ref=ref, dfm=dfm, A=motion.A, t=motion.t)
            for method in a.methods:
                for tool, py in (("al-dvc", a.aldvc), ("ours", sys.executable)):
                    r = _run(py, "ours" if tool == "ours" else "aldvc", method, path,
                             a.subset, a.step)
                    rows.append({"case": name, "method": method, "tool": tool, **r})
                    print(json.dumps(rows[-1]), flush=True)
    print("\n| case | method | tool | RMSE (voxel) | valid | POI/s | CPU ms/POI | peak RSS (MB) |\n"
          "|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "error" in r:
            print(f"| {r['case']} | {r['method']} | {r['tool']} | error: {r['error']} |||| ")
            continue
        print(f"| {r['case']} | {r['method']} | {r['tool']} | {r['rmse']:.4f} | "
              f"{100 * r['valid']:.1f} % | {r['poi_s']:.0f} | {r['cpu_ms_per_poi']:.2f} | "
              f"{r['peak_rss_mb']:.0f} |")


if __name__ == "__main__":
    main()
