"""The kernels' argument types listed ahead (kernels.signatures) and the
precompiling in parallel processes (workflow.precompile, issue 25).

The list cannot go stale unnoticed: a fresh process runs a Local, an AL-DIC,
a tracked and a strain analysis, records every kernel Python calls with the
argument types, and each must be listed (the failure prints what to add).
"""

from __future__ import annotations

import importlib
import inspect
import json
import os
import subprocess
import sys

import pytest

from napari_aldic.engine import precompile_kernels
from napari_aldic.engine.kernels import signatures as sigs
from napari_aldic.engine.workflow.precompile import kernels_to_compile

#: run in a fresh interpreter: every (kernel, argument types) called from
#: Python, as ``kernels.signatures`` spells them, one JSON line
_PROBE = r"""
import json
import numba.core.dispatcher as D
import numpy as np
from napari_aldic.engine.kernels.signatures import spell

calls = {}
_orig = D.Dispatcher._compile_for_args

def _record(self, *args, **kws):  # a Python call with new argument types
    out = _orig(self, *args, **kws)
    mod = self.py_func.__module__
    if mod.startswith("napari_aldic.engine.kernels."):
        name = mod.rsplit(".", 1)[1] + "." + self.py_func.__name__
        calls.setdefault(name, set()).update(spell(s) for s in self.signatures)
    return out

D.Dispatcher._compile_for_args = _record
from napari_aldic.engine import compute_strain, correlate, synthetic, track

size = 112
field = synthetic.Affine.strain_rotation(exx=0.003, eyy=-0.001, center=(56, 56), t=(0.4, -0.3))
ref, dfm = synthetic.speckle_pair((size, size), field, seed=3)
roi = np.ones((size, size), bool)
roi[48:64, 48:64] = False  # a hole
for method in ("local", "aldic"):
    res = correlate(ref, dfm, roi=roi, subset=21, step=8, method=method)
compute_strain(res, window=3, method="plane_fit")
track(np.stack([ref, dfm, dfm]), subset=21, step=8, method="local")
print(json.dumps({k: sorted(v) for k, v in calls.items()}))
"""


def _python(code: str, env=None) -> str:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=1200)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout.strip().splitlines()[-1]


def test_every_listed_signature_parses_and_fits_its_kernel():
    grouped = [n for names in sigs.GROUPS.values() for n in names]
    assert sorted(grouped) == sorted(sigs.KERNELS)  # each kernel in exactly one group
    for name, spelled in sigs.KERNELS.items():
        module, func = name.split(".")
        disp = getattr(importlib.import_module(f"napari_aldic.engine.kernels.{module}"), func)
        n_params = len(inspect.signature(disp.py_func).parameters)
        for s in spelled:
            args = sigs.parse(s)
            assert sigs.spell(args) == s  # one spelling, so the list compares as text
            assert len(args) == n_params, f"{name}: {s} has {len(args)} of {n_params}"


def test_every_kernel_call_of_an_analysis_is_listed():
    calls = json.loads(_python(_PROBE))
    assert {"icgn.icgn_affine", "icgn.icgn_translation", "moments.moments_kernel",
            "lattice.plane_fit"} <= set(calls)  # the probe sees the analyses' kernels
    missing = {name: [s for s in spelled if s not in sigs.KERNELS.get(name, ())]
               for name, spelled in calls.items()}
    missing = {k: v for k, v in missing.items() if v}
    assert not missing, ("add these to KERNELS in engine/kernels/signatures.py (and the "
                         "kernel to a GROUPS entry):\n" + "\n".join(
                             f'    "{k}": {tuple(v)!r},' for k, v in missing.items()))


@pytest.mark.parametrize("fork", ["1", "0"])
def test_precompiled_kernels_load_from_the_cache_in_a_new_process(tmp_path, fork):
    """Worker processes, forked (the CLI's case on Linux) or fresh interpreters,
    write the cache under the key this process looks up."""
    if fork == "1" and not sys.platform.startswith("linux"):
        pytest.skip("workers are forked on Linux only")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"),
               NAPARI_ALDIC_PRECOMPILE_FORK=fork)
    groups = ("static.lag_peaks", "lattice.median_flags", "lattice.plane_fit",
              "speckle.speckle_intensity")  # enough work to share between two processes
    code = ("from napari_aldic.engine import precompile_kernels as p; import json; "
            f"r = p({groups!r}, workers=2); "
            "print(json.dumps([r.processes, sorted(r.compiled), r.errors, r.start]))")
    processes, compiled, errors, start = json.loads(_python(code, env))
    assert processes == 2 and errors == []
    assert start == ("fork" if fork == "1" else "spawn")
    assert compiled == sorted(groups)
    left = ("from napari_aldic.engine.workflow.precompile import kernels_to_compile as k; "
            f"print(k({groups!r}))")
    assert _python(left, env) == "[]"


def test_precompile_returns_at_once_when_cached():
    first = precompile_kernels(("strain",), workers=1)  # compiles or finds it cached
    assert first.errors == []
    assert kernels_to_compile(("strain",)) == []
    again = precompile_kernels(("strain",))
    assert again.processes == 0 and again.compiled == [] and again.seconds < 1.0


def test_workers_are_not_forked_from_a_thread():
    """A GUI or a thread pool calls from a thread: forking there could leave a
    lock held in the child, so fresh interpreters are started instead."""
    import threading

    from napari_aldic.engine.workflow.precompile import _can_fork

    seen = []
    t = threading.Thread(target=lambda: seen.append(_can_fork()))
    t.start()
    t.join()
    assert seen == [False]


def test_kernels_sharing_helpers_compile_in_one_process():
    """The translation IC-GN kernel calls the affine one's compiled step
    (``gauss_newton.gn_step``): shared between processes it is compiled twice
    (3.4 s instead of 1.6 s), so the shares keep the two together, in order;
    so too the moments' centring after the moments kernel (0.68 s against 0.3 s)."""
    from napari_aldic.engine.kernels import signatures as sigs
    from napari_aldic.engine.workflow.precompile import _shares

    names = [n for n, _ in sigs.entries(("local", "aldic"))]
    for n in (2, 3, 4):
        shares = _shares(names, n, 0.1)
        assert sorted(k for s in shares for k in s) == sorted(names)
        for base, after in (("icgn.icgn_affine", "icgn.icgn_translation"),
                            ("moments.moments_kernel", "moments.centre_moments")):
            (share,) = [s for s in shares if base in s]
            assert share.index(after) == share.index(base) + 1
    # alone (the affine kernel cached already), it is a unit of its own
    assert _shares(["icgn.icgn_translation", "moments.moments_kernel"], 2, 0.1) == [
        ["moments.moments_kernel"], ["icgn.icgn_translation"]]


def test_gn_step_compiles_once_for_both_solvers(tmp_path):
    """A literal ``False`` for ``quad`` made the affine solver compile its own
    ``gn_step`` (Numba types a literal argument apart); both solvers must call
    one specialisation (compiled here in a process with an empty cache)."""
    import os
    import subprocess
    import sys

    code = ("from napari_aldic.engine.kernels import gauss_newton, signatures as sigs\n"
            "from napari_aldic.engine.workflow.precompile import _dispatcher\n"
            "for name in ('icgn.icgn_affine', 'icgn.icgn_translation'):\n"
            "    disp = _dispatcher(name)\n"
            "    for s in sigs.KERNELS[name]:\n"
            "        disp.compile(sigs.parse(s))\n"
            "print(len(gauss_newton.gn_step.signatures))\n")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True)
    assert out.stdout.split()[-1] == "1"


@pytest.mark.parametrize("fork", ["1", "0"])
def test_background_precompile_is_collected_by_the_next_call(tmp_path, fork):
    """``background=True`` returns at once with the workers compiling; the next
    call collects them (their kernels in its report, its seconds from their
    start) and compiles what else it needs, and the cache then holds it all."""
    if fork == "1" and not sys.platform.startswith("linux"):
        pytest.skip("workers are forked on Linux only")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"),
               NAPARI_ALDIC_PRECOMPILE_FORK=fork)
    first = ("static.lag_peaks", "lattice.median_flags")
    code = ("import json, time; from napari_aldic.engine import precompile_kernels as p\n"
            "from napari_aldic.engine.workflow.precompile import kernels_to_compile as k\n"
            f"t = time.perf_counter(); b = p({first!r}, workers=2, background=True)\n"
            "started = time.perf_counter() - t\n"
            "time.sleep(1.0)\n"
            f"t = time.perf_counter(); f = p({first!r} + ('lattice.plane_fit',), workers=1)\n"
            "call = time.perf_counter() - t\n"
            "print(json.dumps([started, b.processes, b.seconds, sorted(b.compiled), "
            f"sorted(f.compiled), f.seconds - call, f.errors, "
            f"k({first!r} + ('lattice.plane_fit',))]))")
    started, procs, b_secs, b_names, f_names, before_call, errors, left = json.loads(
        _python(code, env))
    assert started < 1.0 and procs == 2 and b_secs == 0.0  # returned before compiling
    assert b_names == sorted(first)
    assert f_names == sorted(first + ("lattice.plane_fit",)) and errors == []
    # counted from the background start: the second of sleep before the call included
    assert 1.0 <= before_call < 1.0 + started + 0.5
    assert left == []


def test_one_call_collects_every_background_run(tmp_path):
    """Two background runs (the second for what the first does not compile):
    the next call waits for both, compiling nothing again, and none is left
    in flight (a second run left behind would be compiled twice, then killed)."""
    if not sys.platform.startswith("linux"):
        pytest.skip("workers are forked on Linux only")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    both = ("static.lag_peaks", "lattice.median_flags")
    code = ("import json; from napari_aldic.engine import precompile_kernels as p\n"
            "from napari_aldic.engine.workflow import precompile as m\n"
            f"a = p({both[:1]!r}, workers=1, background=True)\n"
            f"b = p({both!r}, workers=1, background=True)\n"
            f"f = p({both!r}, workers=1)\n"
            "print(json.dumps([a.compiled, b.compiled, sorted(f.compiled), f.processes, "
            f"len(m._RUNNING), m.kernels_to_compile({both!r})]))")
    a, b, f_names, procs, left_runs, left = json.loads(_python(code, env))
    assert a == list(both[:1]) and b == list(both[1:])
    assert f_names == sorted(both) and procs == 2  # the two workers, nothing here
    assert left_runs == 0 and left == []


def test_uncollected_background_workers_are_stopped_at_exit(tmp_path):
    """A command that ends before its analysis (an error, --help) leaves no
    compiling process behind."""
    if not sys.platform.startswith("linux"):
        pytest.skip("workers are forked on Linux only")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    code = ("from napari_aldic.engine import precompile_kernels as p\n"
            "from napari_aldic.engine.workflow import precompile as m\n"
            "p(('static.lag_peaks', 'lattice.median_flags'), workers=2, "
            "background=True)\n"
            "print(' '.join(str(w.pid) for r in m._RUNNING for w, _ in r.procs))")
    pids = [int(x) for x in _python(code, env).split()]
    assert len(pids) == 2
    for pid in pids:  # killed and reaped by the exiting process: no such process
        assert not os.path.exists(f"/proc/{pid}"), f"worker {pid} outlived its parent"
