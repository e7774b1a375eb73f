"""bench_scale.py ``memory`` and ``tiled``: peak memory and accuracy of pairs
larger than memory (see bench_scale.py's docstring)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bigpair  # noqa: E402

_CHILD = """
import json, sys, time
sys.path.insert(0, {here!r})
import bigpair
from napari_aldic.engine import correlate, correlate_tiled
from napari_aldic.engine.io import read_image
t = time.perf_counter()
if {tiled!r}:
    res = correlate_tiled({ref!r}, {dfm!r}, step={step}, workers={workers}, method={method!r})
else:
    res = correlate(read_image({ref!r}), read_image({dfm!r}), step={step}, method={method!r})
print("RESULT", json.dumps(dict(bigpair.errors(res), seconds=time.perf_counter() - t,
                                timing=res.meta.get("timing", {{}}))))
"""


def _measured(cmd: list[str]) -> dict:
    """Run ``cmd`` under /usr/bin/time: peak RSS (MiB), wall time, its stdout."""
    t = time.perf_counter()
    p = subprocess.run(["/usr/bin/time", "-f", "MAXRSS %M"] + cmd, capture_output=True,
                       text=True)
    wall = time.perf_counter() - t
    if p.returncode != 0:
        raise RuntimeError(f"{cmd[:3]} failed:\n{p.stdout[-2000:]}\n{p.stderr[-2000:]}")
    rss = next(int(line.split()[1]) for line in p.stderr.splitlines()
               if line.startswith("MAXRSS"))
    return {"peak_rss_mib": round(rss / 1024, 1), "wall_s": round(wall, 1), "stdout": p.stdout}


def _child(ref, dfm, step: int, tiled: bool, workers: int, method: str = "local") -> dict:
    code = _CHILD.format(here=str(HERE), ref=str(ref), dfm=str(dfm), step=step, tiled=tiled,
                         workers=workers, method=method)
    out = _measured([sys.executable, "-c", code])
    line = next(ln for ln in out.pop("stdout").splitlines() if ln.startswith("RESULT"))
    return {**out, **json.loads(line.split(" ", 1)[1])}


def memory_rows(size: int, step: int, data: Path, keep: bool, workers: int,
                method: str = "local", untiled: bool = True) -> dict:
    """Peak RSS of an untiled and a tiled run of a ``size``² pair."""
    ref, dfm = bigpair.write_pair(data, size)
    try:
        rows = {"size": size, "step": step, "method": method,
                "tiled": _child(ref, dfm, step, True, workers, method)}
        if untiled:
            rows["untiled"] = _child(ref, dfm, step, False, workers, method)
    finally:
        if not keep:
            ref.unlink(), dfm.unlink()
    return rows


def tiled_cli(size: int, step: int, data: Path, keep: bool, workers: int,
              method: str = "local", untiled: bool = True) -> dict:
    """``napari-aldic run`` on a ``size``² tiled BigTIFF pair (time, peak RSS,
    accuracy), and a 2048² pair of the same generator correlated in memory."""
    from napari_aldic.engine import load_result

    t = time.perf_counter()
    ref, dfm = bigpair.write_pair(data, size)
    gen = time.perf_counter() - t
    out = data / f"out_{size}.npz"
    cli = shutil.which("napari-aldic") or "napari-aldic"
    try:
        run = _measured([cli, "run", str(ref), str(dfm), "--step", str(step),
                         "--method", method, "--tile-workers", str(workers), "-o", str(out)])
        res = load_result(out)
        row = {"size": size, "step": step, "method": method,
               "file_gb": round(ref.stat().st_size / 1e9, 2),
               "generated_s": round(gen, 1), "cli": {k: run[k] for k in ("peak_rss_mib",
                                                                         "wall_s")},
               "tiled": res.meta.get("tiled"), "timing": res.meta.get("timing"),
               "admm_iterations": len(res.meta.get("admm_history", [])),
               **bigpair.errors(res)}
    finally:
        if not keep:
            for p in (ref, dfm, out):
                p.unlink(missing_ok=True)
    if not untiled:
        return row
    small = bigpair.write_pair(data, 2048)
    row["small_2048_in_memory"] = _child(*small, step, False, workers, method)
    if not keep:
        small[0].unlink(), small[1].unlink()
    return row


_CORNER = """
import json, resource, sys, time
sys.path.insert(0, {here!r})
import bigpair, zarr
from napari_aldic.engine import correlate_tiled
n, c = {size}, {corner}
roi = zarr.create_array(store={{}}, shape=(n, n), chunks=(2048, 2048), dtype=bool,
                        fill_value=False)
roi[n - c:n, n - c:n] = True
t = time.perf_counter()
res = correlate_tiled({ref!r}, {dfm!r}, roi=roi, step={step}, workers={workers},
                      method={method!r})
print("RESULT", json.dumps(dict(bigpair.errors(res), seconds=time.perf_counter() - t,
                                blocks=res.meta["tiled"]["blocks"])))
"""


def corner(size: int, step: int, data: Path, keep: bool, workers: int,
           method: str = "local", untiled: bool = True, corner_px: int = 4096) -> dict:
    """A ``corner_px``² ROI in the far corner (largest motion) of a ``size``²
    pair, tiled: every block is visited, those of the ROI correlated."""
    ref, dfm = bigpair.write_pair(data, size)
    code = _CORNER.format(here=str(HERE), size=size, corner=corner_px, ref=str(ref),
                          dfm=str(dfm), step=step, workers=workers, method=method)
    out = _measured([sys.executable, "-c", code])
    line = next(ln for ln in out.pop("stdout").splitlines() if ln.startswith("RESULT"))
    if not keep:
        ref.unlink(), dfm.unlink()
    return {"size": size, "corner": corner_px, **out, **json.loads(line.split(" ", 1)[1])}
