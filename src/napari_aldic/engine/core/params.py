"""Analysis parameters: one typed, validated dataclass.

Every length is in pixels of the reference image; every tolerance states its unit.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from numbers import Integral, Real
from typing import Any, Literal, NoReturn

import numpy as np

from .reasons import DICError

__all__ = ["DICParams", "StrainParams", "MAX_ITER_CAP", "ADMM_ITER_CAP", "MIN_TOL",
           "SMOOTH_CANDIDATES", "ADAPTIVE_WINDOW"]

#: caps on the iteration counts: more never helps, and a huge value would make
#: a failing node (or ADMM loop) look like a hung program
MAX_ITER_CAP = 10_000
ADMM_ITER_CAP = 1_000
#: largest thin-plate smoothing length ``smooth`` (px)
SMOOTH_MAX = 1e4
#: ``smooth="auto"``: candidate smoothing lengths, in units of the subset width
#: (ratio ~sqrt 2). Local errors are correlated over about one subset width; at
#: most half a subset keeps (about) the spatial resolution of the subsets, and
#: even a perfectly smooth field gains little beyond that. AL-DIC and AL-DVC.
SMOOTH_CANDIDATES = (0.0, 0.09, 0.125, 0.18, 0.25, 0.35, 0.5)
#: adaptive smoothing: each length's risk is averaged over a Gaussian window of
#: this standard deviation (in subset widths) around each node
ADAPTIVE_WINDOW = 1.0
#: finest IC-GN tolerance (pixels): float32 interpolation noise is about 1e-7 px
MIN_TOL = 1e-6

Method = Literal["local", "aldic"]
Init = Literal["fft", "seeds"]


@dataclass(frozen=True)
class DICParams:
    """Parameters of a 2-D DIC analysis.

    Attributes
    ----------
    subset : int, default 31
        Full width of the square correlation subset in pixels (odd, >= 7).
        31 means 31 x 31 pixels, half-width ``h = 15`` (iDICs convention).
    step : int, default 8
        Node spacing in pixels (>= 1). Nodes sit at ``h + 1 + k * step``
        along each axis, so the full subset of every node lies inside the
        image with a one-pixel margin.
    method : {"local", "aldic"}, default "local"
        ``"local"``: subset-wise IC-GN only. ``"aldic"``: augmented
        Lagrangian DIC (ADMM local/global iterations).
    init : {"fft", "seeds"}, default "fft"
        Initial guess: FFT normalised cross-correlation, or propagation from
        user seed points.
    seeds : tuple of (x, y), default ()
        Seed points in pixels (x = column, y = row) for ``init="seeds"``.
    search : int, default 20
        Initial half-range of the cross-correlation search in pixels: shifts
        in ``[-search, search]`` along each axis are tested first. ``correlate``
        clips it (and ``search_max``) to the image's larger side.
    search_max : int or None, default None
        Largest half-range the search may widen to (pixels) when a peak lies
        on the border of the tested range or is too weak. ``None`` means a
        quarter of the larger image side, at least ``4 * search``.
    init_spacing : int or None, default None
        Spacing in pixels of the coarse nodes that get a cross-correlation
        guess; the other nodes start from their nearest converged coarse
        node (first-order extrapolation with its gradient). ``None`` picks
        the multiple of ``step`` closest to ``2 * subset``. ``step`` (or any
        value <= step) correlates every node.
    anchor_spacing : int or None, default None
        Spacing in pixels of the anchor nodes: a sparse subset of the coarse
        nodes searched first over the widening range; each coarse node's
        search is then centred on the motion predicted from its nearest
        matched anchor (first-order, with the anchor's gradient), and tested
        first over at most 8 px around it (widened as any search), so large
        and spatially varying motion costs no wider searches. ``None`` picks
        4 x the coarse spacing; ``0`` turns anchors off (every coarse node
        searched around zero motion).
    interpolation : {"auto", "cubic", "quintic"}, default "auto"
        B-spline order used to sample the deformed image at sub-pixel
        positions (coefficients are precomputed once per image). ``"auto"``
        uses cubic, and quintic when the speckle is very fine (reference
        autocorrelation half-width under 1.8 px), where cubic splines leave a
        sub-pixel bias of 0.005-0.01 px; the choice is in ``res.meta``.
    shape_function : {"affine", "quadratic"}, default "affine"
        Subset shape function of Local IC-GN. ``"affine"``: the subset
        stretches, shears and rotates (6 parameters). ``"quadratic"``: it may
        also bend (12 parameters, second derivatives of ``u`` and ``v``),
        which keeps the amplitude of displacements varying over a subset
        width (finer spatial resolution) at some cost in noise and speed.
        With ``method="aldic"`` it applies to the initial Local step; the
        ADMM local steps bend subsets with the global field instead
        (``second_order_warp``).
    max_iter : int, default 40
        Iteration cap of the IC-GN solver per node (at most
        :data:`MAX_ITER_CAP`).
    tol : float, default 1e-3
        Convergence tolerance in pixels on the IC-GN parameter update
        ``sqrt(du^2 + dv^2 + (h*d(du/dx))^2 + ...)`` (gradient terms scaled by
        the half-width so all terms are displacements at the subset edge); at
        least :data:`MIN_TOL`.
    zncc_min : float, default 0.6
        Nodes whose final zero-normalised cross-correlation is lower are
        retried from an individual cross-correlation guess and, if still
        lower, flagged unreliable (``valid=False``).
    zncc_rel : float, default 3.0
        Relative correlation test: a node is also flagged (``POOR_MATCH``)
        when ``1 - ZNCC > 0.1 + zncc_rel * s2 / V``, with ``V`` the grey-level
        variance of its subset and ``s2`` the residual per pixel of a correct
        match (the median over converged nodes, at most twice the image noise
        variance measured in the images): it matches far worse than image
        noise allows, as spurious matches of material that left the field of
        view or moved beyond the search range do. ``0`` disables it.
    max_uncertainty : float or None, default 0.1
        Largest standard uncertainty (pixels, one sigma) of ``u`` or ``v`` of
        a valid node, predicted from the subset's Gauss-Newton matrix and its
        match residual; noisier nodes are flagged ``UNCERTAIN`` (at 0.1 px an
        error over 0.5 px is a five-sigma event). ``None`` disables the test.
    min_component : float, default 0.5
        Smallest fraction of the full subset area that the mask-connected
        component containing the node must keep; smaller ones are flagged.
    refine : {None, "light", "medium", "strong"}, default None
        Adaptive quadtree refinement preset (``correlate(refine=...)`` also
        takes a full :class:`~napari_aldic.engine.dic.quadtree.Refinement`).
    mu : float, default 0.1
        AL-DIC displacement penalty, dimensionless: the local step's penalty
        stiffness is ``mu`` times the subset's mean Gauss-Newton stiffness.
    beta : float, default 0.1
        AL-DIC gradient penalty, dimensionless: ``β/μ = beta * step**2`` in
        the global solve, so the smoothing it implies scales with the node
        spacing. Larger values make the global field smoother.
    smooth : "auto" or float, default "auto"
        AL-DIC thin-plate regularisation: the smoothing length ``ℓ`` in
        pixels of an extra global-step term, the squared second derivatives
        of ``û`` (zero for uniform strain and rigid motion; a displacement
        wave of wavenumber ``k`` is damped by ``1/(1 + (kℓ)^4)``). ``"auto"``
        chooses ``ℓ`` per image pair, at most half a subset, by minimising
        Stein's unbiased risk estimate with the noise predicted from the
        images (noise-free pairs get ~0); ``0`` runs plain Algorithm 1. See
        :mod:`napari_aldic.engine.regularise`. AL-DVC (``correlate_volume``)
        uses the same term in 3-D, its length chosen per node the same way
        (voxels; :mod:`napari_aldic.engine.volume.smoothing`).
    second_order_warp : bool, default True
        Allow the AL-DIC local step to bend each subset with the global
        field's second derivatives too (held fixed, from ``û`` smoothed over
        half the subset half-width), not only its gradient. An affine subset
        averages curvature away (a displacement wave loses about
        ``(k h)^2 / 6`` of its amplitude); the second-order warp removes that
        bias but, being a deconvolution, amplifies noise. With
        ``smooth="auto"`` it is used only where the risk estimate says it
        pays (``meta["regularisation"]["second_order_warp"]``); with a fixed
        ``smooth`` it is used as set. ``False`` keeps the paper's affine warp.
    admm_max_iter : int, default 8
        Cap on ADMM iterations (at most :data:`ADMM_ITER_CAP`).
    admm_tol : float, default 1e-3
        ADMM stops when the RMS change of the global displacement between
        iterations is below this (pixels).
    n_threads : int or None, default None
        Threads for the Numba kernels; ``None`` uses Numba's default (all
        cores).
    extra : dict
        Run-time settings that are not analysis parameters (not compared,
        not saved): ``"jacobian_sigma"`` (px, the smoothing of the IC-GN
        steepest-descent images, chosen once for a whole tiled pair),
        ``"image_var"`` (grey levels², the pair's image noise variance, measured
        once for a whole tiled pair), ``"guess_of_this_pair": True`` (the
        ``guess`` of ``correlate`` is a coarse result of the same pair: IC-GN
        starts from it directly instead of searching around it) and
        ``"quality": False`` (skip the speckle-quality and uncertainty maps,
        e.g. for a tiled run's coarse initial guess, whose only use is to
        start the nodes).

    Raises
    ------
    ValueError
        ``Invalid DIC parameter: ...`` for any field of the wrong type (text
        where a number belongs, a bool, a malformed seed list), NaN or
        infinity, or a value out of its range; the message names the field.
    """

    subset: int = 31
    step: int = 8
    method: Method = "local"
    init: Init = "fft"
    seeds: tuple[tuple[float, float], ...] = ()
    search: int = 20
    search_max: int | None = None
    init_spacing: int | None = None
    anchor_spacing: int | None = None
    interpolation: Literal["auto", "cubic", "quintic"] = "auto"
    shape_function: Literal["affine", "quadratic"] = "affine"
    max_iter: int = 40
    tol: float = 1e-3
    zncc_min: float = 0.6
    zncc_rel: float = 3.0
    max_uncertainty: float | None = 0.1
    min_component: float = 0.5
    refine: str | None = None
    mu: float = 0.1
    beta: float = 0.1
    smooth: float | str = "auto"
    second_order_warp: bool = True
    admm_max_iter: int = 8
    admm_tol: float = 1e-3
    n_threads: int | None = None
    extra: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        for name in ("subset", "step", "search", "max_iter", "admm_max_iter"):
            object.__setattr__(self, name, _integer(name, getattr(self, name)))
        for name in ("search_max", "init_spacing", "anchor_spacing", "n_threads"):
            object.__setattr__(self, name, _integer(name, getattr(self, name), optional=True))
        for name in ("tol", "zncc_min", "zncc_rel", "min_component", "mu", "beta", "admm_tol"):
            object.__setattr__(self, name, _number(name, getattr(self, name)))
        if self.smooth != "auto":
            object.__setattr__(self, "smooth", _number("smooth", self.smooth, "'auto' or "))
        if self.max_uncertainty is not None:
            object.__setattr__(self, "max_uncertainty",
                               _number("max_uncertainty", self.max_uncertainty, "None or "))
        object.__setattr__(self, "seeds", _seed_points(self.seeds))
        if not isinstance(self.second_order_warp, (bool, np.bool_)):
            _bad(f"second_order_warp={self.second_order_warp!r} must be True or False")
        object.__setattr__(self, "second_order_warp", bool(self.second_order_warp))
        self._check_choices()
        self._check_ranges()

    def _check_choices(self) -> None:
        _choice("method", self.method, ("local", "aldic"))
        _choice("init", self.init, ("fft", "seeds"))
        _choice("interpolation", self.interpolation, ("auto", "cubic", "quintic"))
        _choice("shape_function", self.shape_function, ("affine", "quadratic"))
        if self.refine is not None:
            _choice("refine", self.refine, ("light", "medium", "strong", "none"), "None, ")
        if self.init == "seeds" and not self.seeds:
            _bad("init='seeds' needs at least one seed point (x, y)")

    def _check_ranges(self) -> None:
        if self.subset < 7 or self.subset % 2 == 0:
            _bad(f"subset={self.subset} must be an odd full width >= 7 pixels (e.g. 31)",
                 "not_odd", name="subset", value=self.subset)
        if self.step < 1:
            _bad(f"step={self.step} must be >= 1 pixel")
        if self.search < 1:
            _bad(f"search={self.search} must be >= 1 pixel")
        if self.search_max is not None and self.search_max < self.search:
            _bad(f"search_max={self.search_max} must be >= search={self.search}")
        if self.init_spacing is not None and self.init_spacing < 1:
            _bad(f"init_spacing={self.init_spacing} must be >= 1 pixel or None")
        if self.anchor_spacing is not None and self.anchor_spacing < 0:
            _bad(f"anchor_spacing={self.anchor_spacing} must be >= 0 pixels (0: no anchors) "
                 "or None")
        if not 1 <= self.max_iter <= MAX_ITER_CAP:
            _bad(f"max_iter={self.max_iter} must be between 1 and {MAX_ITER_CAP}")
        if not (MIN_TOL <= self.tol < 1):
            _bad(f"tol={self.tol} must be in [{MIN_TOL:g}, 1) pixel: a finer tolerance is "
                 "below what float32 images resolve, so no node would converge")
        if not (-1 <= self.zncc_min < 1):
            _bad(f"zncc_min={self.zncc_min} must be in [-1, 1)")
        if self.zncc_rel < 0:
            _bad(f"zncc_rel={self.zncc_rel} must be >= 0 (0 disables the relative test)")
        if self.max_uncertainty is not None and not self.max_uncertainty > 0:
            _bad(f"max_uncertainty={self.max_uncertainty} must be > 0 pixels or None")
        if not (0 < self.min_component <= 1):
            _bad(f"min_component={self.min_component} must be in (0, 1]")
        if not self.mu > 0:
            _bad(f"mu={self.mu} must be > 0")
        if not self.beta > 0:
            _bad(f"beta={self.beta} must be > 0")
        if self.smooth != "auto" and not 0 <= self.smooth <= SMOOTH_MAX:
            # beyond it, smooth**4 swamps the data term in double precision: the
            # global solve is singular or silently returns a flat field
            _bad(f"smooth={self.smooth!r} must be 'auto' or a length in pixels between 0 "
                 f"and {SMOOTH_MAX:g}")
        if not 1 <= self.admm_max_iter <= ADMM_ITER_CAP:
            _bad(f"admm_max_iter={self.admm_max_iter} must be between 1 and {ADMM_ITER_CAP}")
        if not (0 < self.admm_tol < 1):
            _bad(f"admm_tol={self.admm_tol} must be in (0, 1) pixel")
        if self.n_threads is not None and self.n_threads < 1:
            _bad(f"n_threads={self.n_threads} must be >= 1 or None")

    @property
    def half(self) -> int:
        """Subset half-width ``h`` in pixels."""
        return self.subset // 2

    def resolved_init_spacing(self) -> int:
        """Coarse-node spacing in pixels, a multiple of ``step``."""
        if self.init_spacing is not None:
            return max(self.step, (self.init_spacing // self.step) * self.step)
        k = max(1, round(2 * self.subset / self.step))
        return k * self.step

    def resolved_anchor_spacing(self) -> int:
        """Anchor-node spacing in pixels, a multiple of the coarse spacing (0: none)."""
        coarse = self.resolved_init_spacing()
        if self.anchor_spacing is None:
            return 4 * coarse
        if self.anchor_spacing == 0:
            return 0
        return max(coarse, (self.anchor_spacing // coarse) * coarse)

    def resolved_search_max(self, shape: tuple[int, int]) -> int:
        """Largest search half-range in pixels for an image of ``shape`` (at
        most the image's larger side)."""
        top = max(int(shape[0]), int(shape[1]), 1)
        if self.search_max is not None:
            return max(min(self.search_max, top), min(self.search, top))
        return min(max(4 * self.search, max(shape) // 4), top)

    def fitted_to(self, shape: tuple[int, int]) -> DICParams:
        """These parameters with ``search`` and ``search_max`` clipped to the
        larger side of an image of ``shape``: a larger shift moves every subset
        out of the image, and testing it would only cost memory and time."""
        top = max(int(shape[0]), int(shape[1]), 1)
        changes = {}
        if self.search > top:
            changes["search"] = top
        if self.search_max is not None and self.search_max > top:
            changes["search_max"] = top
        return self.replace(**changes) if changes else self

    def replace(self, **changes: Any) -> DICParams:
        """Return a copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def combine(cls, params: DICParams | None, kwargs: dict[str, Any] | None = None,
                **named: Any) -> DICParams:
        """The parameters of one call of ``correlate``/``track``/``correlate_tiled``.

        One rule: every argument given explicitly overrides ``params``
        (``DICParams()`` when None), also when it equals the default.
        ``named`` are the call's ``subset``/``step``/``method`` arguments
        (``None``: not given); ``kwargs`` its other fields (all given).
        """
        changes = {k: v for k, v in named.items() if v is not None}
        changes.update(kwargs or {})
        if params is None:
            return cls(**changes)
        if isinstance(params, dict):  # the fields of a DICParams, e.g. from a JSON file
            params = cls.from_dict(params)
        if not isinstance(params, DICParams):
            raise TypeError(f"params must be a DICParams (or a dict of its fields), not "
                            f"{type(params).__name__}")
        return params.replace(**changes) if changes else params

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dictionary of the parameters."""
        d = dataclasses.asdict(self)
        d.pop("extra")
        d["seeds"] = [list(s) for s in self.seeds]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DICParams:
        """Build parameters from a dictionary, rejecting unknown keys."""
        if not isinstance(d, dict):
            raise ValueError("DIC parameters must be a dictionary (JSON object) of DICParams "
                             f"fields, not {type(d).__name__}")
        names = {f.name for f in dataclasses.fields(cls)} - {"extra"}
        unknown = sorted(set(map(str, d)) - names)
        if unknown:
            raise ValueError(
                f"Unknown DIC parameter(s) {unknown}; valid names are {sorted(names)}"
            )
        return cls(**d)


# ------------------------------------------------------------------ checks
def _bad(msg: str, code: str = "invalid_parameter", **fields) -> NoReturn:
    raise DICError(code, f"Invalid DIC parameter: {msg}", **fields)


def _integer(name: str, val, optional: bool = False) -> int | None:
    """``val`` as an int: integers and whole finite floats (JSON, CLI) pass."""
    if val is None and optional:
        return None
    if isinstance(val, (bool, np.bool_)) or not isinstance(val, Real):
        _bad(f"{name}={val!r} must be an integer{' or None' if optional else ''}, not "
             f"{type(val).__name__}")
    if isinstance(val, Integral):
        return int(val)
    if not math.isfinite(val):
        _bad(f"{name}={val!r} must be a finite integer (got NaN or infinity)")
    if not float(val).is_integer():
        _bad(f"{name}={val!r} must be an integer")
    return int(val)


def _number(name: str, val, also: str = "") -> float:
    """``val`` as a finite float (no bool, no text, no NaN or infinity)."""
    if isinstance(val, (bool, np.bool_)) or not isinstance(val, Real):
        _bad(f"{name}={val!r} must be {also}a number, not {type(val).__name__}")
    if not math.isfinite(val):
        _bad(f"{name}={val!r} must be {also}a finite number (got NaN or infinity)")
    return float(val)


def _choice(name: str, val, choices: tuple[str, ...], also: str = "") -> None:
    if not isinstance(val, str) or val not in choices:
        names = ", ".join(repr(c) for c in choices[:-1]) + f" or {choices[-1]!r}"
        _bad(f"{name}={val!r} must be {also}{names}")


def _seed_points(seeds) -> tuple[tuple[float, float], ...]:
    """Seeds as a tuple of finite ``(x, y)`` pixel coordinates."""
    if seeds is None:
        return ()
    example = "a list of (x, y) points in pixels, e.g. [[120, 80], [300, 80]]"
    if isinstance(seeds, (str, bytes, dict)) or not isinstance(seeds, Iterable):
        _bad(f"seeds={seeds!r} must be {example}")
    out = []
    for i, pt in enumerate(seeds):
        if isinstance(pt, (str, bytes, dict)) or not isinstance(pt, Iterable) or \
                len(pt := list(pt)) != 2:
            _bad(f"seed {i} = {pt!r} must be one (x, y) point: two numbers in pixels "
                 f"(seeds must be {example})")
        out.append(tuple(_number(f"seed {i} {axis}", v) for axis, v in zip("xy", pt)))
    return tuple(out)


@dataclass(frozen=True)
class StrainParams:
    """How strain is computed from a displacement field: the one place of the
    strain defaults (``compute_strain``, settings files, the CLI and the dock).

    Attributes
    ----------
    window : int, default 5
        Odd number of nodes across the plane fit (>= 3).
    method : {"plane_fit", "fem"}, default "plane_fit"
    measure : {"green_lagrange", "infinitesimal", "euler_almansi"}, default "green_lagrange"
    """

    window: int = 5
    method: str = "plane_fit"
    measure: str = "green_lagrange"

    def to_dict(self) -> dict[str, Any]:
        """The settings file's "strain" section."""
        return dataclasses.asdict(self)
