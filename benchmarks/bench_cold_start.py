"""Cold and warm start of napari-aldic beside pyALDIC's cold start, in one session.

Each case runs as a fresh process, timed from its start to its exit (the
time to the first result, imports and Numba compilation included):

* cold: ``NUMBA_CACHE_DIR`` points at a new empty folder, so every kernel
  is compiled;
* warm: the same command again with that folder, now holding the cache.

Cases: ``napari-aldic demo`` (512² synthetic pair, Local), ``napari-aldic run``
on the open-hole tension (OHT) pair with ``--method local`` and
``--method aldic``, and pyALDIC (``benchmarks/pyaldic_runner.py``, one
repeat, no warm-up) Local and AL-DIC on the same pair, cold.

Usage::

    python benchmarks/bench_cold_start.py --pyaldic /work/pyaldic-venv/bin/python \\
        [--cases demo local aldic local-serial py-local py-aldic] [--json OUT.json]

``local-serial`` (``aldic-serial``, ``demo-serial``): the same command with
``NAPARI_ALDIC_PRECOMPILE_WORKERS=1`` (the kernels compiled in the process
itself, no worker processes). CPU seconds (``*_cpu_s``, worker processes
included) are printed beside the wall-clock ones, for a loaded machine.

Prints one JSON line per case and the targets: ours cold <= 0.5 x pyALDIC
cold, and ours cold <= 1.5 x ours warm + 20 s.

Our package's modules are byte-compiled first (``compileall``), as pip does
when it installs a wheel (pyALDIC's venv has them from its install): an
editable install under ``PYTHONDONTWRITEBYTECODE=1`` would otherwise compile
every module's source at each start (~0.2 s here). ``--no-bytecode`` skips it.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
DATA = HERE.parent.parent / "shared" / "data" / "open_hole_tension"
if not DATA.is_dir():
    DATA = Path("/work/shared/data/open_hole_tension")
PAIR = [str(DATA / "oht_cfrp_00.tiff"), str(DATA / "oht_cfrp_11.tiff")]


_CPU = {"cpu_s": 0.0}


def _timed(cmd: list[str], cache: Path, cwd: Path, env_extra=None) -> tuple[float, str]:
    """Wall seconds of ``cmd``; its CPU seconds (its worker processes
    included) are left in ``_CPU["cpu_s"]``."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), **(env_extra or {}))
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True)
    secs = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    _CPU["cpu_s"] = round(r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime, 2)
    if out.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{out.stderr[-2000:]}")
    return secs, out.stdout + out.stderr


def _ours(case: str, work: Path) -> list[str]:
    cli = [sys.executable, "-m", "napari_aldic.cli"]
    if case == "demo":
        return cli + ["demo", "--out", str(work / "demo")]
    return cli + ["run", *PAIR, "--subset", "31", "--step", "8", "--method", case,
                  "--tile-size", "0", "-o", str(work / f"{case}.npz")]


def _pyaldic(python: str, method: str, work: Path) -> list[str]:
    return [python, str(HERE / "pyaldic_runner.py"), *PAIR, "--subset", "31", "--step", "8",
            "--method", method, "--repeat", "1", "--no-warmup",
            "--out", str(work / f"py_{method}.npz")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pyaldic", default="/work/pyaldic-venv/bin/python")
    ap.add_argument("--cases", nargs="+",
                    default=["py-local", "py-aldic", "demo", "local", "aldic"])
    ap.add_argument("--json", type=Path)
    ap.add_argument("--no-bytecode", action="store_true",
                    help="do not byte-compile napari_aldic first (see the module docstring)")
    args = ap.parse_args()
    if not args.no_bytecode:
        import compileall
        import importlib.util

        pkg = Path(importlib.util.find_spec("napari_aldic").origin).parent
        compileall.compile_dir(str(pkg), quiet=1)
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for case in args.cases:
            cache = work / f"cache-{case}"
            cache.mkdir()
            if case.startswith("py-"):
                cmd = _pyaldic(args.pyaldic, case[3:], work)
                cold, _ = _timed(cmd, cache, work)
                row = {"case": case, "cold_s": round(cold, 2), "cold_cpu_s": _CPU["cpu_s"]}
            else:  # "local-serial": precompiling in the process itself (1 worker)
                serial = case.endswith("-serial")
                cmd = _ours(case.removesuffix("-serial"), work)
                extra = {"NAPARI_ALDIC_PRECOMPILE_WORKERS": "1"} if serial else None
                cold, text = _timed(cmd, cache, work, extra)
                cold_cpu = _CPU["cpu_s"]
                warm, _ = _timed(cmd, cache, work, extra)
                row = {"case": case, "cold_s": round(cold, 2), "cold_cpu_s": cold_cpu,
                       "warm_s": round(warm, 2), "warm_cpu_s": _CPU["cpu_s"],
                       "compile_lines": [ln.strip() for ln in text.splitlines()
                                         if "compil" in ln.lower()][:4]}
            rows[case] = row
            print(json.dumps(row), flush=True)
    for ours, ref in (("local", "py-local"), ("aldic", "py-aldic")):
        if ours in rows and ref in rows:
            c, w, p = rows[ours]["cold_s"], rows[ours]["warm_s"], rows[ref]["cold_s"]
            print(json.dumps({"target": ours, "cold_over_pyaldic_cold": round(c / p, 3),
                              "ok_half_pyaldic": c <= 0.5 * p,
                              "cold_minus_1.5warm": round(c - 1.5 * w, 2),
                              "ok_warm_plus_20": c <= 1.5 * w + 20}))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
