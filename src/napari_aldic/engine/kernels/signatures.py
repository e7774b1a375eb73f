"""The argument types each top-level kernel is called with, spelled out ahead
of time (issue 25: the first run).

Numba compiles a kernel for the argument types of its first call, a minute or
more in all on a small machine. Knowing those types in advance lets
``workflow.precompile`` compile the kernels before the analysis, in several
processes at once that share Numba's disk cache (one process compiles one
kernel at a time: Numba holds a global compiler lock).

:data:`KERNELS` maps ``"module.function"`` (a module of ``engine/kernels``) to
its signatures, each a Numba signature string of the argument types only
(``"(float32[:, ::1], int64)"``: ``::1`` marks the contiguous axis, as
``numba.core.sigutils`` reads it). Only the kernels Python calls are listed:
the helpers they call are compiled with them. ``tests/engine/
test_kernel_signatures.py`` runs a Local, an AL-DIC and a tracked analysis and
fails, printing the entries to add, when a kernel is called with types that
are not here (a changed kernel argument list, a new kernel).

:data:`GROUPS` says which analyses need a kernel, :data:`COST` the seconds of
one compilation measured on one core (relative weights for sharing the work
between processes).
"""

from __future__ import annotations

from numba.core import sigutils, types

__all__ = ["KERNELS", "GROUPS", "COST", "AFTER", "spell", "parse", "entries"]

_F32_2 = "float32[:, ::1]"
_F64_1 = "float64[::1]"
_F64_2 = "float64[:, ::1]"
_I64_1 = "int64[::1]"
_I32_1 = "int32[::1]"


def _sig(*args: str) -> str:
    return "(" + ", ".join(args) + ("," if len(args) == 1 else "") + ")"


KERNELS: dict[str, tuple[str, ...]] = {
    "bspline.spline_gradients": (_sig(_F32_2, _F64_1, _F64_1, _F32_2, _F32_2),),
    "prefilter.prefilter_2d": (_sig(_F64_2, _F64_1, "float64"),),
    "prefilter.symmetric_fir_2d": (_sig(_F64_2, _F64_1, _F64_2),),
    "sums.window_sums": (_sig("float32[:, :, ::1]", "int64"),),
    "icgn.icgn_affine": (_sig(
        "int64", "int64", _F32_2, _F32_2, _F32_2, _F32_2, _F32_2, _F32_2, "int64", _I64_1,
        _I64_1, _F64_2, "boolean[::1]", _I32_1, "uint8[:, :, ::1]", "int64", "int64",
        "float64", _F64_2, _F64_1, _I32_1, "int8[::1]", _F64_2, _F32_2,
        "UniTuple(float64, 3)", _F64_2),),
    "lattice.median_flags": (_sig(
        "int64", "int64", _F64_1, _F64_1, "boolean[::1]", "int64[:, ::1]", "float64",
        "float64", "int64", "boolean[::1]"),),
    "moments.moments_kernel": (_sig(
        _F32_2, _F32_2, _F32_2, _F32_2, _F32_2, "boolean[:, ::1]", "boolean[::1]",
        "int64[:, ::1]", _I64_1, _I64_1, _I64_1, _I64_1, _I64_1, _I64_1, _I64_1, _F64_1,
        _F64_1, _I64_1, _I64_1, "int64", "int64", _F64_1, _F64_1, _F64_2),),
    "moments.centre_moments": (_sig(_F64_2, _F64_1, _F64_1, "int64"),),
    "static.lag_peaks": (_sig(
        "int64", "int64", _F32_2, _I64_1, _I64_1, _I32_1, "uint8[:, :, ::1]", "int64",
        "int64[:, :, ::1]", _I64_1, "int64", _F64_2),),
    # AL-DIC only
    "icgn.icgn_translation": (_sig(
        "int64", "int64", _F32_2, _F32_2, _F32_2, _F32_2, _F32_2, _F32_2, "int64", _I64_1,
        _I64_1, _F64_2, _F64_2, _F64_2, _F64_2, _F64_2, "boolean[::1]", "UniTuple(float64, 2)",
        "float64", "boolean[::1]", _I32_1, "uint8[:, :, ::1]", "int64", "int64", "float64",
        _F64_2, _F64_1, _I32_1, "int8[::1]"),),
    "cg.jacobi_cg": (_sig(_I32_1, _I32_1, _F64_1, _F64_1, _F64_2, _F64_2, _F64_1, "int64",
                          _I64_1),),
    "cg.triangular_solve": (_sig(_I32_1, _I32_1, _F64_1, _F64_2, "boolean"),),
    "noise_sums.noise_window_sums": (_sig(
        _F32_2, _F32_2, "boolean[:, ::1]", "uint8[:, ::1]", "float32[:, :, ::1]", "int64",
        _I64_1, _I64_1, _I64_1, _I64_1, _I64_1, _I64_1, _I64_1, _I64_1,
        "float64[:, :, ::1]"),),
    # strain (plane fit)
    "lattice.plane_fit": (_sig(
        _F64_1, _F64_1, _F64_1, _F64_1, "boolean[::1]", "int64[:, ::1]", "int64", _F64_2),),
    # the synthetic speckle images (demo, sample data)
    "speckle.speckle_intensity": (_sig(
        _F64_1, _F64_1, _F64_1, _F64_1, _F64_1, _F64_1, _I64_1, "float64", "float64",
        "float64", "int64", "int64", "float64", "float64", _F64_1),),
}

#: which analyses need a kernel: "local" every 2-D analysis (AL-DIC starts
#: with a Local step), "aldic" AL-DIC's global steps, "strain" the strain's
#: plane fit, "synthetic" the synthetic speckle images
GROUPS: dict[str, tuple[str, ...]] = {
    "local": ("bspline.spline_gradients", "prefilter.prefilter_2d",
              "prefilter.symmetric_fir_2d", "sums.window_sums", "icgn.icgn_affine",
              "lattice.median_flags", "moments.moments_kernel", "moments.centre_moments",
              "static.lag_peaks"),
    "aldic": ("icgn.icgn_translation", "cg.jacobi_cg", "cg.triangular_solve",
              "noise_sums.noise_window_sums"),
    "strain": ("lattice.plane_fit",),
    "synthetic": ("speckle.speckle_intensity",),
}

#: compile seconds of a kernel's signatures on one core (helpers included,
#: each compiled alone in a fresh process after a trivial warm-up; measured
#: 2026-12-04 on a 2-core EPYC, several runs each, the AL-DIC, strain and
#: synthetic kernels 2026-12-03 on a 2-core Xeon, the multi-column jacobi_cg
#: 2026-12-07 (2.1-2.4 s against the one-column kernel's 1.2 s on that EPYC VM);
#: see benchmarks/RESULTS.md, issue 25): relative weights for sharing the work between processes;
#: unlisted: 1 s
COST: dict[str, float] = {
    "icgn.icgn_affine": 6.0, "moments.moments_kernel": 4.6, "icgn.icgn_translation": 3.4,
    "static.lag_peaks": 1.65, "lattice.median_flags": 0.7,
    "cg.jacobi_cg": 1.6,
    "speckle.speckle_intensity": 1.0,
    "bspline.spline_gradients": 0.22, "sums.window_sums": 0.55,
    "moments.centre_moments": 0.68, "lattice.plane_fit": 0.8, "cg.triangular_solve": 0.2,
    # 2026-12-07, fifteenth session (2.6-3.5 s alone on the EPYC VM)
    "noise_sums.noise_window_sums": 3.0,
    # 2026-12-07, sixteenth session (1.8-2.9 s and 0.8-1.0 s alone on the EPYC VM)
    "prefilter.prefilter_2d": 2.0, "prefilter.symmetric_fir_2d": 0.8,
}

#: kernels that compile much faster in the process that compiles another one
#: first, because they call the same compiled helpers (the IC-GN step, the
#: subset gathering; the moments' centring, ``moments._centre_rows``):
#: ``kernel: (the other kernel, its seconds after it)``
AFTER: dict[str, tuple[str, float]] = {
    "icgn.icgn_translation": ("icgn.icgn_affine", 1.6),
    "moments.centre_moments": ("moments.moments_kernel", 0.3),  # 0.68 s alone
}


def entries(groups=("local", "aldic")) -> list[tuple[str, tuple[str, ...]]]:
    """``(kernel, signatures)`` of the kernels the named :data:`GROUPS` need
    (an item of ``groups`` may also name one kernel, ``"module.function"``)."""
    names = [n for g in groups for n in (GROUPS[g] if g in GROUPS else (g,))]
    return [(n, KERNELS[n]) for n in dict.fromkeys(names)]


def parse(sig: str) -> tuple:
    """The argument types (Numba types) of a signature string of :data:`KERNELS`."""
    args, _ = sigutils.normalize_signature(sig)
    return tuple(args)


def _spell_one(t) -> str:
    if isinstance(t, types.Array) and t.mutable and t.aligned:
        axes = [":"] * t.ndim
        if t.layout == "C":
            axes[-1] = "::1"
        elif t.layout == "F":
            axes[0] = "::1"
        return f"{_spell_one(t.dtype)}[{', '.join(axes)}]"
    if isinstance(t, types.UniTuple):
        return f"UniTuple({_spell_one(t.dtype)}, {t.count})"
    if isinstance(t, types.Tuple):
        return _sig(*(_spell_one(x) for x in t.types)).replace("(", "Tuple((", 1) + ")"
    if t == types.boolean:
        return "boolean"
    if isinstance(t, (types.Integer, types.Float, types.Complex)):
        return str(t)
    raise ValueError(f"no signature spelling for Numba type {t!r}")


def spell(argtypes) -> str:
    """A signature string for a tuple of Numba argument types (``parse``'s inverse)."""
    return _sig(*(_spell_one(t) for t in argtypes))
