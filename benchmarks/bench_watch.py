"""Latency of live DIC (``napari-aldic watch``) with the simulated camera.

The camera (``python -m napari_aldic.engine.synthetic.camera``, its own
process) writes FRAMES frames of SIZE² px, one every INTERVAL s, in a write
style, with junk files and a zero-byte file completed later; the watch (the
CLI, its own process) analyses them; this script reads the run folder with
``load_run`` every 20 ms meanwhile and notes when each frame's result first
appears. Latency = that time - the time the camera finished the frame file
(``camera_log.csv``). Afterwards ``napari-aldic run`` of the same folder is
compared with the live result, and the watch's exit with its idle timeout.

Usage: ``python benchmarks/bench_watch.py [--frames 20] [--size 512]
[--interval 1.5] [--style chunks rename] [--threads 2]``. Prints one line per
style.
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from napari_aldic.engine import load_run

SRC = Path(__file__).resolve().parents[1] / "src"


def _spawn(*args) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(SRC) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.Popen([sys.executable, "-m", *map(str, args)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _poll(out: Path, proc: subprocess.Popen) -> tuple[dict, int, float]:
    """Frame -> first time (time.time()) its result file was there (looked
    for every 20 ms); ``load_run`` failures once the folder was readable
    (``load_run`` every 0.2 s: reading every frame's header each time would
    itself load the two cores); the time the watch exited."""
    seen, fails, ok_once, last_load = {}, 0, False, 0.0
    while proc.poll() is None:
        now = time.time()
        for p in out.glob("frame_*.npz") if out.is_dir() else []:
            k = int(p.stem.split("_")[1])
            seen.setdefault(k, now)
        if now - last_load > 0.2:
            last_load = now
            try:
                seq = load_run(out)
                ok_once = True
                present = [i for i, ok in enumerate(seq.frames.present) if ok]
                _ = seq.frames[present[-1]].u  # the newest frame reads whole
            except (FileNotFoundError, ValueError):
                fails += ok_once
        time.sleep(0.02)
    return seen, fails, time.time()


def bench(style: str, frames: int, size: int, interval: float, threads: int,
          idle: float) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="bench_watch_"))
    cam, out = tmp / "cam", tmp / "run"
    camera = _spawn("napari_aldic.engine.synthetic.camera", cam, "--frames", frames,
                    "--interval", interval, "--style", style, "--size", size, "--junk",
                    "--zero-byte", frames // 2)
    watch = _spawn("napari_aldic.cli", "watch", cam, "-o", out, "--idle-timeout", idle,
                   "--threads", threads)
    seen, fails, t_exit = _poll(out, watch)
    camera.wait()
    text = watch.stdout.read()
    secs = [float(line.split(": ")[1].split(" s")[0]) for line in text.splitlines()
            if line.startswith("frame ")]
    log = {int(r["frame"]): float(r["complete_time"])
           for r in csv.DictReader(open(cam / "camera_log.csv"))}
    lat = np.array([seen[k] - log[k] for k in range(1, frames) if k in seen])
    offline = _spawn("napari_aldic.cli", "run", cam, "-o", tmp / "offline", "--threads", threads)
    offline.communicate()
    live, off = load_run(out), load_run(tmp / "offline")
    diff = max(float(np.nanmax(np.abs(np.r_[live[k].u - off[k].u, live[k].v - off[k].v])))
               for k in range(1, frames))
    return {"style": style, "frames": len(lat), "rc": watch.returncode, "load_run_fails": fails,
            "median_s": float(np.median(lat)), "max_s": float(np.max(lat)),
            "max_diff_px": diff, "exit_after_last_s": t_exit - max(log.values()),
            "frame_s": float(np.median(secs)) if secs else float("nan")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--interval", type=float, default=1.5)
    ap.add_argument("--style", nargs="+", default=["chunks", "rename"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--idle", type=float, default=5.0)
    args = ap.parse_args()
    print(f"load {os.getloadavg()[0]:.2f}; {args.frames} frames of {args.size}² every "
          f"{args.interval} s, {args.threads} threads")
    for style in args.style:
        r = bench(style, args.frames, args.size, args.interval, args.threads, args.idle)
        print(f"{r['style']:7s} frames {r['frames']}, rc {r['rc']}, load_run failures "
              f"{r['load_run_fails']}, latency median {r['median_s']:.2f} s, max "
              f"{r['max_s']:.2f} s (a frame's correlation and save: median {r['frame_s']:.2f} s), "
              f"live - offline {r['max_diff_px']:.1e} px, exit "
              f"{r['exit_after_last_s']:.1f} s after the last frame (idle {args.idle} s); "
              f"load {os.getloadavg()[0]:.2f}", flush=True)


if __name__ == "__main__":
    main()
