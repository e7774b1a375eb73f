"""A simulated camera: a synthetic speckle sequence with known truth, written
into a folder at a given rate, the way camera software writes frames.

::

    python -m napari_aldic.engine.synthetic.camera OUT --frames 20 --interval 1.5 \\
        --style chunks

* ``--style chunks``: each frame is written at its final name
  (``frame_00007.tif``) in several chunks with pauses between them;
  ``--style rename``: under a temporary name (``frame_00007.tif.tmp``),
  renamed when complete;
* ``--zero-byte K``: frame K's file is created empty one interval early and
  filled at its time (cameras that create the file first);
* ``--stall K:S``: frame K's writer stops halfway for S seconds;
* ``--junk``: files that are not frames (``notes.txt``, ``Thumbs.db``).

The motion is a uniaxial test: frame k is stretched by ``k * rate`` along x
(Poisson 0.3 along y) about the image centre and moved by ``k * drift`` px.
``OUT/truth.json`` holds the field of every frame (``Affine`` parameters) and
``OUT/camera_log.csv`` the time (``time.time()``) each frame file was
complete, for latency measurements (``benchmarks/bench_watch.py``).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from .speckle import Affine, make_pattern, render

__all__ = ["frame_field", "render_frames", "write_frame", "run_camera"]


def frame_field(k: int, shape, rate: float = 0.002, drift: float = 0.3) -> Affine:
    """The displacement of frame ``k`` (frame 0: none)."""
    h, w = shape
    return Affine.strain_rotation(exx=k * rate, eyy=-0.3 * k * rate,
                                  center=((w - 1) / 2, (h - 1) / 2),
                                  t=(k * drift, 0.5 * k * drift))


def render_frames(n: int, shape=(512, 512), rate: float = 0.002, drift: float = 0.3,
                  noise: float = 1.0, seed: int = 0) -> list[np.ndarray]:
    """The ``n`` frames of the sequence (8-bit)."""
    pat = make_pattern(shape, speckle_radius=2.5, seed=seed, margin=64.0 + n * drift)
    return [render(pat, shape, None if k == 0 else frame_field(k, shape, rate, drift),
                   n_quad=2, noise=noise, seed=seed + 1 + k) for k in range(n)]


def _tiff_bytes(img: np.ndarray) -> bytes:
    import tifffile

    buf = io.BytesIO()
    tifffile.imwrite(buf, img)
    return buf.getvalue()


def write_frame(path: Path, img: np.ndarray, style: str = "chunks", chunks: int = 4,
                pause: float = 0.05, stall: float = 0.0) -> float:
    """Write one frame as a camera does; returns the time (``time.time()``)
    it was complete at ``path``."""
    data = _tiff_bytes(img)
    target = path if style == "chunks" else path.with_name(path.name + ".tmp")
    cuts = np.linspace(0, len(data), chunks + 1).astype(int)
    with open(target, "wb") as fh:
        for j, (a, b) in enumerate(zip(cuts, cuts[1:])):
            fh.write(data[a:b])
            fh.flush()
            if j < chunks - 1:
                time.sleep(stall if stall and j == chunks // 2 - 1 else pause)
    if style == "rename":
        os.replace(target, path)
    return time.time()


def run_camera(out, frames: int = 20, interval: float = 1.5, style: str = "chunks",
               size: int = 512, rate: float = 0.002, drift: float = 0.3,
               zero_byte: int | None = None, stall: tuple[int, float] | None = None,
               junk: bool = False, seed: int = 0, chunks: int = 4, start: int = 0,
               quiet: bool = False) -> Path:
    """Write frames ``start`` to ``frames - 1`` into ``out``, one every
    ``interval`` seconds (frames are rendered first); returns ``out``."""
    if style not in ("chunks", "rename"):
        raise ValueError(f"style={style!r} must be 'chunks' or 'rename'")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    shape = (size, size)
    if not quiet:
        print(f"camera: rendering {frames} frames of {size} x {size} px", flush=True)
    imgs = render_frames(frames, shape, rate, drift, seed=seed)
    truth = [{"frame": k, "G": [list(r) for r in frame_field(k, shape, rate, drift).G],
              "center": list(frame_field(k, shape, rate, drift).center),
              "t": list(frame_field(k, shape, rate, drift).t)} for k in range(frames)]
    (out / "truth.json").write_text(json.dumps(truth, indent=1))
    if junk:
        (out / "notes.txt").write_text("operator notes, not a frame\n")
        (out / "Thumbs.db").write_bytes(os.urandom(512))
    log = out / "camera_log.csv"
    if start == 0 or not log.exists():
        log.write_text("frame,file,complete_time\n")
    t_next = time.monotonic()
    for k in range(start, frames):
        t_next += interval if k > start else 0.0
        time.sleep(max(0.0, t_next - time.monotonic()))
        if zero_byte is not None and k == zero_byte - 1:
            (out / f"frame_{zero_byte:05d}.tif").touch()
        pause = stall[1] if stall is not None and stall[0] == k else 0.0
        path = out / f"frame_{k:05d}.tif"
        done = write_frame(path, imgs[k], style, chunks=chunks, stall=pause)
        with open(log, "a") as fh:
            fh.write(f"{k},{path.name},{done:.6f}\n")
        if not quiet:
            print(f"camera: frame {k} -> {path.name}", flush=True)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m napari_aldic.engine.synthetic.camera",
                                description="Write a synthetic speckle sequence into a "
                                "folder at a given rate, as a camera does.")
    p.add_argument("out", type=Path)
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--interval", type=float, default=1.5, help="seconds between frames")
    p.add_argument("--style", choices=("chunks", "rename"), default="chunks")
    p.add_argument("--size", type=int, default=512, help="frames of N x N pixels")
    p.add_argument("--rate", type=float, default=0.002, help="strain added per frame")
    p.add_argument("--drift", type=float, default=0.3, help="px moved per frame")
    p.add_argument("--chunks", type=int, default=4, help="chunks per frame file")
    p.add_argument("--zero-byte", type=int, dest="zero_byte", metavar="K")
    p.add_argument("--stall", metavar="K:S", help="frame K's writer pauses S s halfway")
    p.add_argument("--junk", action="store_true", help="also write files that are not frames")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--start", type=int, default=0, help="first frame to write")
    args = p.parse_args(argv)
    stall = None
    if args.stall:
        k, s = args.stall.split(":")
        stall = (int(k), float(s))
    run_camera(args.out, args.frames, args.interval, args.style, args.size, args.rate,
               args.drift, args.zero_byte, stall, args.junk, args.seed, args.chunks,
               args.start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
