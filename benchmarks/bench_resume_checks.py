"""Cost of the issue-23 run-folder checks: the digest of each frame as it is read,
and what a resume of a finished run now does (every finished frame's file CRC-checked
and its image read and hashed again, the field store's slices read).

Usage: ``python benchmarks/bench_resume_checks.py [--frames 20] [--size 512]``. Prints
the seconds of: one frame digest, the first run, a resume with nothing left to do, and
the check of one frame file (``frame_file_meta``).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile

from napari_aldic.engine import synthetic as S, track
from napari_aldic.engine.core.files import array_digest
from napari_aldic.engine.workflow.runfolder import frame_file_meta


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--size", type=int, default=512)
    a = ap.parse_args()
    shape = (a.size, a.size)
    pat = S.make_pattern(shape, seed=3, margin=32)
    stack = np.stack([S.render(pat, shape, None if k == 0 else S.Translation(0.05 * k, 0),
                               n_quad=1, seed=k) for k in range(a.frames)]).astype(np.uint16)
    with tempfile.TemporaryDirectory() as tmp:
        tif = Path(tmp) / "stack.tif"
        tifffile.imwrite(tif, stack, photometric="minisblack")
        t = time.perf_counter()
        for _ in range(20):
            array_digest(stack[1])
        digest = (time.perf_counter() - t) / 20
        t = time.perf_counter()
        track(tif, subset=31, step=16, out_dir=Path(tmp) / "run")
        first = time.perf_counter() - t
        t = time.perf_counter()
        track(tif, subset=31, step=16, out_dir=Path(tmp) / "run")
        resume = time.perf_counter() - t
        t = time.perf_counter()
        frame_file_meta(Path(tmp) / "run" / "frame_00001.npz")
        one = time.perf_counter() - t
    print(f"{a.frames} frames of {a.size}^2 uint16, subset 31, step 16")
    print(f"  digest of one frame        {digest * 1e3:8.2f} ms")
    print(f"  first run                  {first:8.2f} s")
    print(f"  resume, nothing to do      {resume:8.2f} s")
    print(f"  CRC + header of one frame  {one * 1e3:8.2f} ms")


if __name__ == "__main__":
    main()
