"""Sequence throughput and lazy reading of a stack larger than 4 GB.

Usage::

    python benchmarks/bench_sequence.py              # both parts
    python benchmarks/bench_sequence.py --skip-big   # frames per minute only

1. Frames per minute for a 20-frame 1024 x 1024 synthetic sequence (uniform
   stretch growing 0 -> 2 %, 2 grey levels of noise, subset 31, step 8),
   Local DIC and AL-DIC, accumulative, sequential (previous frame as the
   guess) and with ``scheduler="threads"``; error of the last frame against
   the exact truth.
2. Peak RSS (VmHWM of a fresh process) of ``track`` over a multi-page 16-bit
   TIFF larger than 4 GB (4096 x 4096 frames), read lazily page by page:
   frames 0, 64 and the last one are analysed (step 16).
The stacks are generated once into ``benchmarks/_cache/`` (not tracked).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CACHE = HERE / "_cache"
N, FRAMES = 1024, 20


def field(k: int):
    from napari_aldic.engine import synthetic as S

    e = 0.02 * k / (FRAMES - 1)
    return S.Affine.strain_rotation(exx=e, eyy=-0.3 * e, center=(N / 2, N / 2),
                                    t=(0.3 * k, -0.2 * k))


def sequence_stack() -> np.ndarray:
    from napari_aldic.engine import synthetic as S

    CACHE.mkdir(exist_ok=True)
    p = CACHE / f"seq_{N}_{FRAMES}.npy"
    if not p.exists():
        pat = S.make_pattern((N, N), seed=7, margin=80)
        frames = [S.render(pat, (N, N), None if k == 0 else field(k), noise=2.0, seed=k,
                           n_quad=3) for k in range(FRAMES)]
        np.save(p, np.stack(frames))
    return np.load(p, mmap_mode="r")


def frames_per_minute(method: str, scheduler) -> dict:
    from napari_aldic.engine import track

    stack = sequence_stack()
    track(stack[:2, :256, :256], method=method)  # JIT warm-up
    t = time.perf_counter()
    seq = track(stack, subset=31, step=8, method=method, scheduler=scheduler)
    el = time.perf_counter() - t
    last = seq[FRAMES - 1]
    ut, vt = field(FRAMES - 1).displacement(last.x, last.y)
    v = last.valid
    rmse = float(np.sqrt(np.mean((last.u[v] - ut[v]) ** 2 + (last.v[v] - vt[v]) ** 2)))
    return {"method": method, "scheduler": str(scheduler), "seconds": el,
            "frames_per_minute": (FRAMES - 1) / el * 60, "rmse_last_px": rmse,
            "valid_last": float(v.mean())}


_BIG_CHILD = r"""
import json, sys, time
from napari_aldic.engine import track
def hwm():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
path, last = sys.argv[1], int(sys.argv[2])
t = time.perf_counter()
seq = track(path, step=16, frames=[0, 64, last])
print(json.dumps({"seconds": time.perf_counter() - t, "peak_rss_mb": hwm(),
                  "valid_last": float(seq[2].valid.mean())}))
"""


def big_stack() -> tuple[Path, int]:
    import tifffile

    from napari_aldic.engine import synthetic as S

    p = CACHE / "big_4096_u16.tif"
    n_frames = 130  # 130 x 32 MiB = 4.2 GB
    if not p.exists():
        pat = S.make_pattern((4096, 4096), seed=3, margin=40)
        base = S.render(pat, (4096, 4096), None, bit_depth=16, n_quad=2)
        with tifffile.TiffWriter(p, bigtiff=True) as tw:
            for k in range(n_frames):
                # integer shifts of one analytic image: exact truth, cheap to make
                tw.write(np.roll(base, (k % 7, k % 5), axis=(0, 1)), photometric="minisblack",
                         contiguous=True)
    return p, n_frames


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--skip-big", action="store_true")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    out = {"fpm": [], "big": None}
    for method in ("local", "aldic"):
        for sched in (None, "threads"):
            r = frames_per_minute(method, sched)
            out["fpm"].append(r)
            print(f"{method:5s} scheduler={str(sched):7s} {r['frames_per_minute']:6.1f} frames/min"
                  f" ({FRAMES - 1} pairs of {N}^2 in {r['seconds']:.1f} s; last frame RMSE "
                  f"{r['rmse_last_px']:.4f} px, {r['valid_last']:.1%} valid)", flush=True)
    if not args.skip_big:
        path, n = big_stack()
        size = path.stat().st_size / 1e9
        res = subprocess.run([sys.executable, "-c", _BIG_CHILD, str(path), str(n - 1)],
                             capture_output=True, text=True, check=True)
        r = json.loads(res.stdout.strip().splitlines()[-1])
        r["file_gb"] = size
        out["big"] = r
        print(f"lazy {size:.2f} GB stack (4096^2 uint16, {n} frames): track of 3 frames "
              f"peak RSS {r['peak_rss_mb']:.0f} MB in {r['seconds']:.1f} s", flush=True)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
