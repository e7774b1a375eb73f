"""Numba compilation options, defined once for every kernel of the engine.

Use them as ``@nb.njit(**PARALLEL, fastmath=FASTMATH)`` and so on. Changing
one of them changes the compiled code, and with fast-math possibly the last
digits of the results.

Numba's on-disk cache (``cache=True``) is keyed by the source file of the
compiled kernel only: after editing a helper that a kernel of *another*
module inlines, delete the ``__pycache__/*.nbi``/``*.nbc`` files of
``kernels/`` (or set ``NUMBA_CACHE_DIR``) so the kernels are rebuilt.
"""

from __future__ import annotations

__all__ = ["FASTMATH", "FASTMATH_ALL", "CACHED", "SERIAL", "PARALLEL", "INLINE", "CALLEE",
           "SERIAL_CALLEE"]

#: fast-math without the no-NaN/no-inf assumptions, so NaN checks survive:
#: no signed zeros, reciprocals, FMA contraction, approximate functions and
#: re-association (which lets LLVM vectorise the reductions of the hot loops)
FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}

#: every fast-math flag, the no-NaN/no-inf assumptions included (the speckle
#: renderer only; LLVM may then fold its NaN test of the points away: on x86 a
#: point without material renders as the pattern's grey ``lo``)
FASTMATH_ALL = True

#: a serial top-level kernel: compiled once, cached on disk, GIL released
CACHED = {"cache": True, "nogil": True}

#: a serial kernel that was parallel (or a helper such a kernel calls as a
#: function): NumPy's division semantics (x / 0 gives inf or NaN, as in a
#: ``prange`` loop) rather than Python's ZeroDivisionError, which the callers
#: of such kernels do not expect
SERIAL = {"cache": True, "nogil": True, "error_model": "numpy"}

#: a top-level kernel whose outer loop is a ``prange`` over threads
PARALLEL = {"cache": True, "nogil": True, "parallel": True}

#: a helper inlined into its callers at the Numba-IR level; it is compiled
#: with the caller's options (its own ``fastmath`` only matters when it is
#: called from plain Python, and then ``cache`` keeps that compilation too:
#: every kernel of the engine is cached, tests/engine/test_kernel_cache.py)
INLINE = {"inline": "always", "cache": True}

#: a helper that only compiled code calls, as a function (not inlined): no
#: CPython or C-callable wrapper, whose generation, optimisation and machine
#: code cost ~0.1 s of compiling per helper (issue 25: 19 % of the moments
#: kernel's compile time); calling it from Python raises TypeError
CALLEE = {"cache": True, "nogil": True, "no_cpython_wrapper": True, "no_cfunc_wrapper": True}

#: ... the same for a helper of a ``SERIAL`` kernel (NumPy's division semantics)
SERIAL_CALLEE = dict(CALLEE, error_model="numpy")
