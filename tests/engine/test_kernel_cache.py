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
