"""Stage times of Local and AL-DIC run alternately in one process (paired runs on a
shared machine), with wall and CPU seconds, on bench_dic's cached 1024² pair.

Usage (the two trees alternately, so load changes hit both)::

    PYTHONPATH=/path/to/treeA/src python benchmarks/bench_aldic_stages.py --reps 2 > A1.json
    PYTHONPATH=/path/to/treeB/src python benchmarks/bench_aldic_stages.py --reps 2 > B1.json
    python benchmarks/bench_aldic_stages.py --summary A*.json
    python benchmarks/bench_aldic_stages.py --summary B*.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

STAGES = ["prefilter", "init", "icgn", "rescue", "static", "smoothing_choice",
          "admm_global_factorise", "admm_global_solve", "admm_local", "quality", "total"]


def measure(reps: int, size: int = 1024) -> dict:
    import napari_aldic
    from bench_dic import pair_path
    from napari_aldic.engine import correlate

    z = np.load(pair_path(size))
    ref, dfm = z["ref"], z["dfm"]
    for m in ("local", "aldic"):  # JIT warm-up
        correlate(ref[:256, :256], dfm[:256, :256], method=m)
    out = {"src": napari_aldic.__file__, "local": [], "aldic": []}
    for _ in range(reps):
        for m in ("local", "aldic"):
            t, c = time.perf_counter(), time.process_time()
            r = correlate(ref, dfm, subset=31, step=8, method=m)
            out[m].append({"wall": time.perf_counter() - t, "cpu": time.process_time() - c,
                           "valid": int(r.valid.sum()), **r.meta["timing"]})
    return out


def summary(paths) -> None:
    runs = [json.load(open(p)) for p in paths]
    loc = [r for x in runs for r in x["local"]]
    ald = [r for x in runs for r in x["aldic"]]
    print(runs[0]["src"])
    for name, rows in (("local", loc), ("aldic", ald)):
        print(f"  {name}: wall {np.median([r['wall'] for r in rows]):.3f} s, "
              f"CPU {np.median([r['cpu'] for r in rows]):.3f} s (medians of {len(rows)})")
    for key in ("wall", "cpu"):
        ratio = np.median([a[key] / b[key] for a, b in zip(ald, loc)])
        print(f"  AL-DIC / Local ({key}, paired): {ratio:.3f}")
    print("  AL-DIC stages:", {k: round(float(np.median([r.get(k, 0.0) for r in ald])), 3)
                               for k in STAGES})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--summary", nargs="*")
    args = ap.parse_args()
    if args.summary:
        summary(args.summary)
    else:
        print(json.dumps(measure(args.reps)))


if __name__ == "__main__":
    main()
