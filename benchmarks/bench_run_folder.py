"""Size of run-folder frames with a 4096 x 4096 ROI: the ROI copied into every
frame file (``DICResult.save``, as run folders did before format 2) against
one ``roi_<digest>.npz`` per run that the frames refer to (format 2), on disk
and in memory after loading the frames (``load_run``).

Usage: ``python benchmarks/bench_run_folder.py [--frames 10]``. Prints a table.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import tracemalloc
from pathlib import Path

import numpy as np
from scipy import ndimage

from napari_aldic.engine import DICParams, DICResult, load_result, load_run

N = 4096


def _rois() -> dict:
    yy, xx = np.mgrid[:N, :N]
    rng = np.random.default_rng(0)
    blob = ndimage.gaussian_filter(rng.random((N // 16, N // 16)), 2) > 0.5
    return {"whole image (no ROI)": np.ones((N, N), bool),
            "disk": (xx - N / 2) ** 2 + (yy - N / 2) ** 2 < (0.45 * N) ** 2,
            "painted blobs": np.kron(blob, np.ones((16, 16), bool)),
            "random pixels (worst case)": rng.random((N, N)) < 0.5}


def _result(roi: np.ndarray, k: int) -> DICResult:
    """A frame of a 4096^2 image with a 64 px node lattice (nodes do not matter here)."""
    xs = np.arange(32, N - 32, 64)
    gx, gy = np.meshgrid(xs, xs)
    n = gx.size
    z = np.zeros(n)
    return DICResult(x=gx.ravel().astype(float), y=gy.ravel().astype(float), u=z + k,
                     v=z.copy(), dudx=z.copy(), dudy=z.copy(), dvdx=z.copy(), dvdy=z.copy(),
                     valid=np.ones(n, bool), zncc=z + 1, reason=np.zeros(n, np.int8),
                     iterations=np.zeros(n, np.int32),
                     grid_ix=np.tile(np.arange(xs.size), xs.size),
                     grid_iy=np.repeat(np.arange(xs.size), xs.size), grid_xs=xs, grid_ys=xs,
                     image_shape=(N, N), params=DICParams(), meta={"frame": k}, roi=roi)


def _held(load) -> tuple[float, object]:
    tracemalloc.start()
    out = load()
    cur, _ = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return cur / 2**20, out


def measure(frames: int) -> list[dict]:
    from napari_aldic.engine.core.files import write_roi_file

    rows = []
    for name, roi in _rois().items():
        with tempfile.TemporaryDirectory() as tmp:
            old, new = Path(tmp, "old"), Path(tmp, "new")
            old.mkdir()
            new.mkdir()
            for k in range(frames):
                _result(roi, k).save(old / f"frame_{k:05d}.npz")  # ROI inside each frame
            ref = write_roi_file(new, roi)
            for k in range(frames):
                _result(roi, k).save(new / f"frame_{k:05d}.npz", roi_file=ref)
            (new / "sequence.json").write_text(json.dumps({"frames": list(range(frames))}))
            size_old = (old / "frame_00001.npz").stat().st_size
            size_new = (new / "frame_00001.npz").stat().st_size
            roi_file = (new / ref["file"]).stat().st_size
            mem_old, _ = _held(lambda d=old: [load_result(p) for p in sorted(d.glob("*.npz"))])
            mem_new, _ = _held(lambda d=new: load_run(d))
        rows.append({"roi": name, "frame_old_kB": size_old / 1e3,
                     "frame_new_kB": size_new / 1e3, "roi_file_kB": roi_file / 1e3,
                     "mem_old_MB": mem_old, "mem_new_MB": mem_new})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10)
    args = ap.parse_args()
    rows = measure(args.frames)
    print(f"{args.frames} frames of a {N} x {N} image; frame file size (kB) and memory held "
          "after loading all frames (MiB)")
    print(f"{'ROI':28s} {'frame before':>12s} {'frame after':>11s} {'ROI file':>9s} "
          f"{'mem before':>10s} {'mem after':>9s}")
    for r in rows:
        print(f"{r['roi']:28s} {r['frame_old_kB']:12.1f} {r['frame_new_kB']:11.1f} "
              f"{r['roi_file_kB']:9.1f} {r['mem_old_MB']:10.1f} {r['mem_new_MB']:9.1f}")


if __name__ == "__main__":
    main()
