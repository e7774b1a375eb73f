"""Every Numba kernel of engine/kernels is compiled with ``cache=True`` (issue 25).

A kernel without it is compiled again in every new process: a first-run cost
paid on every run. Read from the sources (the decorators), so that nothing
needs compiling here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import napari_aldic.engine.kernels as kernels
from napari_aldic.engine.kernels import flags

KERNELS = Path(kernels.__file__).parent


def _options(call: ast.Call) -> dict:
    """The keyword options of ``@nb.njit(...)``, ``**FLAGS`` dictionaries expanded."""
    opts = {}
    for kw in call.keywords:
        if kw.arg is None:  # **CACHED, **PARALLEL, **INLINE
            opts.update(getattr(flags, kw.value.id))
        else:
            opts[kw.arg] = ast.literal_eval(kw.value) if isinstance(kw.value, ast.Constant) \
                else kw.value
    return opts


def _jit_decorators(tree):
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef):
            for dec in node.decorator_list:
                target = dec.func if isinstance(dec, ast.Call) else dec
                name = target.attr if isinstance(target, ast.Attribute) else \
                    getattr(target, "id", "")
                if name in ("njit", "jit", "vectorize", "guvectorize", "generated_jit"):
                    yield node.name, dec


def test_every_kernel_is_cached():
    found, uncached = 0, []
    for path in sorted(KERNELS.glob("*.py")):
        for name, dec in _jit_decorators(ast.parse(path.read_text(encoding="utf-8"))):
            found += 1
            if not isinstance(dec, ast.Call) or _options(dec).get("cache") is not True:
                uncached.append(f"{path.name}:{name}")
    assert found > 50  # the scan sees the kernels
    assert not uncached, f"kernels without cache=True: {uncached}"


def test_threaded_kernels_divide_as_numpy_does():
    """The node-parallel kernels that ``dic.threads.in_threads`` runs were
    ``prange`` kernels, whose loops divide as NumPy does (x / 0 gives inf or
    NaN); serial, they and the helpers they call as functions must say
    ``error_model="numpy"`` (the ``SERIAL`` flags), or a zero division in a
    node raises ZeroDivisionError out of the whole run. The first serial IC-GN
    kernels had Python's model (``CACHED``)."""
    import napari_aldic.engine.dic as dic

    threaded = set()
    for path in sorted(Path(dic.__file__).parent.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.Call) and getattr(node.func, "id", "") == "in_threads"
                    and node.args and isinstance(node.args[0], ast.Name)):
                threaded.add(node.args[0].id)
    assert {"icgn_affine", "icgn_translation", "icgn_quadratic", "lag_peaks",
            "median_flags"} <= threaded
    helpers = {"gather_subset", "gather_gradients", "affine_reference_sums",
               "zero_motion_evidence"}  # once-per-node functions the IC-GN kernels call
    wrong, seen = [], set()
    for path in sorted(KERNELS.glob("*.py")):
        for name, dec in _jit_decorators(ast.parse(path.read_text(encoding="utf-8"))):
            if name in threaded | helpers:
                seen.add(name)
                if _options(dec).get("error_model") != "numpy":
                    wrong.append(f"{path.name}:{name}")
    assert seen == threaded | helpers
    assert not wrong, f"threaded kernels with Python's division semantics: {wrong}"
