"""Scale benchmark: long sequences on a dask cluster (issue 13, section 3).

Usage::

    python benchmarks/bench_scale.py cluster [--frames 200] [--size 256] [--workers 2]

``cluster``: a ``--frames``-frame ``--size``² uint8 TIFF stack (a speckle
pattern translated by 0.05 px more each frame, 1 grey level of noise) is
tracked by ``track(path, scheduler=client, out_dir=...)`` on a
``LocalCluster`` of ``--workers`` one-thread worker processes (subset 31,
step ``--step``, default 16; accumulative). Reported: the client process's resident memory
(VmRSS; the LocalCluster's scheduler lives in it too) after frame 20 and
after the last frame, frames per second (``--in-memory``: the stack given
as an array), the largest task graph dask warned
about ("Sending large graph"), and the time to read one frame of the TIFF
through one open ``FrameSource`` versus opening the file for every frame.
The stack is generated once into ``benchmarks/_cache/`` (not tracked).

Images larger than memory (section 2)::

    python benchmarks/bench_scale.py memory [--size 10000] [--step 16] [--data /tmp/bigpair]
    python benchmarks/bench_scale.py tiled [--size 40000] [--step 32] [--data /tmp/bigpair]
    (each also with --method aldic, --no-untiled, --keep, --workers N)

``memory``: a ``--size``² uint8 tiled-TIFF pair (``bigpair.py``: analytic
speckle on a periodic cell, a known affine field, 0.5 GL noise) correlated
untiled (both images read whole, ``correlate``) and tiled (``correlate_tiled``
from the files), each in its own process; reported: peak RSS (``/usr/bin/time``
maximum resident set), wall time, RMS and largest error against the field.
``tiled``: the same for ``napari-aldic run REF DEF --step S -o OUT.npz`` on a
``--size``² pair (tiled BigTIFF, 1.6 GB each at 40,000²), and the error of a
2048² pair of the same generator correlated in memory, for comparison. The
pairs are written to ``--data`` and deleted afterwards unless ``--keep``.
``corner``: the ``--size``² pair tiled with a 4096² ROI in its far corner (the
largest motion): every block is visited, only the ROI's are correlated.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CACHE = HERE / "_cache"


def rss_mb() -> float:
    """Resident memory of this process (MB), from /proc."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def make_stack(frames: int, size: int) -> Path:
    import tifffile

    from napari_aldic.engine import synthetic as S

    path = CACHE / f"scale_{frames}x{size}.tif"
    if path.exists():
        return path
    CACHE.mkdir(exist_ok=True)
    pat = S.make_pattern((size, size), seed=3, margin=16)
    stack = np.stack([S.render(pat, (size, size), S.Affine.strain_rotation(t=(0.05 * k, 0.0)),
                               n_quad=1, noise=1.0, seed=k) for k in range(frames)])
    tifffile.imwrite(path, np.clip(stack, 0, 255).astype(np.uint8), photometric="minisblack")
    return path


def tiff_reads(path: Path, n: int = 20) -> dict:
    """ms per frame: one open FrameSource vs a FrameSource (file) per frame."""
    from napari_aldic.engine.io import FrameSource

    with FrameSource(path) as src:
        ks = np.linspace(1, len(src) - 1, n).astype(int)
        t = time.perf_counter()
        for k in ks:
            src[k]
        kept = (time.perf_counter() - t) / n
    t = time.perf_counter()
    for k in ks:
        with FrameSource(path) as one:
            one[k]
    fresh = (time.perf_counter() - t) / n
    return {"open_ms_per_frame": 1e3 * kept, "reopen_ms_per_frame": 1e3 * fresh}


def cluster(frames: int, size: int, workers: int, step: int = 16,
            in_memory: bool = False) -> dict:
    from distributed import Client, LocalCluster

    from napari_aldic.engine import track

    path = make_stack(frames, size)
    if in_memory:  # frames scattered one by one instead of read by the workers
        import tifffile

        stack = tifffile.imread(path)
    out = Path(tempfile.mkdtemp(prefix="bench_scale_"))
    rss: dict = {}
    graphs: list[str] = []
    t0 = time.perf_counter()

    def on_frame(k, res):
        if k in (20, frames - 1):
            rss[k] = rss_mb()

    try:
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                          dashboard_address=None) as lc, Client(lc) as client, \
                warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            start = rss_mb()
            seq = track(stack if in_memory else path, subset=31, step=step, scheduler=client,
                        out_dir=out / "run", on_frame=on_frame)
            graphs = [re.search(r"large graph of size ([\d.]+ \w+)", str(w.message))
                      for w in caught]
            graphs = [g.group(1) for g in graphs if g]
        seconds = time.perf_counter() - t0
        last = seq[frames - 1]
        truth = 0.05 * (frames - 1)
        err = float(np.nanmax(np.abs(last.u[last.valid] - truth)))
    finally:
        shutil.rmtree(out, ignore_errors=True)
    return {"frames": frames, "size": size, "workers": workers, "step": step,
            "in_memory": in_memory,
            "nodes": len(last),
            "client_rss_mb_start": round(start, 1),
            "client_rss_mb_frame20": round(rss[20], 1),
            f"client_rss_mb_frame{frames - 1}": round(rss[frames - 1], 1),
            "rss_growth_mb": round(rss[frames - 1] - rss[20], 1),
            "frames_per_s": round((frames - 1) / seconds, 2),
            "large_graph_warnings": len(graphs), "large_graph_first": graphs[:1],
            "last_frame_max_error_px": round(err, 4),
            **{k: round(v, 2) for k, v in tiff_reads(path).items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", choices=["cluster", "memory", "tiled", "corner"])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--in-memory", action="store_true", dest="in_memory",
                    help="pass the stack as an array instead of its path")
    ap.add_argument("--step", type=int, default=16, help="node spacing (4: ~4k nodes/frame)")
    ap.add_argument("--data", type=Path, default=Path("/tmp/bigpair"),
                    help="memory/tiled: folder of the generated pairs")
    ap.add_argument("--keep", action="store_true", help="keep the generated pairs")
    ap.add_argument("--method", choices=["local", "aldic"], default="local",
                    help="memory/tiled/corner: Local DIC or AL-DIC")
    ap.add_argument("--no-untiled", action="store_false", dest="untiled",
                    help="memory/tiled: skip the in-memory comparison run")
    args = ap.parse_args()
    if args.part == "cluster":
        print(json.dumps(cluster(args.frames, args.size, args.workers, args.step,
                                 args.in_memory), indent=1))
    else:
        from scale_tiles import corner, memory_rows, tiled_cli

        run = {"memory": memory_rows, "tiled": tiled_cli, "corner": corner}[args.part]
        print(json.dumps(run(args.size, args.step, args.data, args.keep, args.workers,
                             args.method, args.untiled), indent=1))


if __name__ == "__main__":
    main()
