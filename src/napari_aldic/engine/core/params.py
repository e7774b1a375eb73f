"""Analysis parameters: one typed, validated dataclass.

Every length is in pixels of the reference image; every tolerance states its unit.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal

__all__ = ["DICParams"]

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
        in ``[-search, search]`` along each axis are tested first.
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
    interpolation : {"auto", "cubic", "quintic"}, default "auto"
        B-spline order used to sample the deformed image at sub-pixel
        positions (coefficients are precomputed once per image). ``"auto"``
        uses cubic, and quintic when the speckle is very fine (reference
        autocorrelation half-width under 1.8 px), where cubic splines leave a
        sub-pixel bias of 0.005-0.01 px; the choice is in ``res.meta``.
    max_iter : int, default 40
        Iteration cap of the IC-GN solver per node.
    tol : float, default 1e-3
        Convergence tolerance in pixels on the IC-GN parameter update
        ``sqrt(du^2 + dv^2 + (h*d(du/dx))^2 + ...)`` (gradient terms scaled by
        the half-width so all terms are displacements at the subset edge).
    zncc_min : float, default 0.6
        Nodes whose final zero-normalised cross-correlation is lower are
        retried from an individual cross-correlation guess and, if still
        lower, flagged unreliable (``valid=False``).
    zncc_rel : float, default 10.0
        Relative correlation test: a node is also flagged when its
        ``1 - ZNCC`` exceeds ``zncc_rel`` times the median ``1 - ZNCC`` of the
        converged nodes (and 0.1), i.e. it matches far worse than the rest of
        the image; this catches spurious matches of material that left the
        field of view. ``0`` disables it.
    min_component : float, default 0.5
        Smallest fraction of the full subset area that the mask-connected
        component containing the node must keep; smaller ones are flagged.
    refine : {None, "light", "medium", "strong"}, default None
        Adaptive quadtree refinement preset (``correlate(refine=...)`` also
        takes a full :class:`~napari_aldic.engine.quadtree.Refinement`).
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
        :mod:`napari_aldic.engine.regularise`.
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
        Cap on ADMM iterations.
    admm_tol : float, default 1e-3
        ADMM stops when the RMS change of the global displacement between
        iterations is below this (pixels).
    n_threads : int or None, default None
        Threads for the Numba kernels; ``None`` uses Numba's default (all
        cores).
    """

    subset: int = 31
    step: int = 8
    method: Method = "local"
    init: Init = "fft"
    seeds: tuple[tuple[float, float], ...] = ()
    search: int = 20
    search_max: int | None = None
    init_spacing: int | None = None
    interpolation: Literal["auto", "cubic", "quintic"] = "auto"
    max_iter: int = 40
    tol: float = 1e-3
    zncc_min: float = 0.6
    zncc_rel: float = 10.0
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
        def bad(msg: str) -> None:
            raise ValueError(f"Invalid DIC parameter: {msg}")

        for name in ("subset", "step", "search", "max_iter", "admm_max_iter"):
            val = getattr(self, name)
            if isinstance(val, bool) or not isinstance(val, int):
                # accept integral floats from JSON/CLI, reject anything else
                if isinstance(val, float) and val.is_integer():
                    object.__setattr__(self, name, int(val))
                else:
                    bad(f"{name}={val!r} must be an integer")
        if self.subset < 7 or self.subset % 2 == 0:
            bad(f"subset={self.subset} must be an odd full width >= 7 pixels (e.g. 31)")
        if self.step < 1:
            bad(f"step={self.step} must be >= 1 pixel")
        if self.method not in ("local", "aldic"):
            bad(f"method={self.method!r} must be 'local' or 'aldic'")
        if self.init not in ("fft", "seeds"):
            bad(f"init={self.init!r} must be 'fft' or 'seeds'")
        if self.search < 1:
            bad(f"search={self.search} must be >= 1 pixel")
        if self.search_max is not None and self.search_max < self.search:
            bad(f"search_max={self.search_max} must be >= search={self.search}")
        if self.init_spacing is not None and self.init_spacing < 1:
            bad(f"init_spacing={self.init_spacing} must be >= 1 pixel or None")
        if self.interpolation not in ("auto", "cubic", "quintic"):
            bad(f"interpolation={self.interpolation!r} must be 'auto', 'cubic' or 'quintic'")
        if self.max_iter < 1:
            bad(f"max_iter={self.max_iter} must be >= 1")
        if not (0 < self.tol < 1):
            bad(f"tol={self.tol} must be in (0, 1) pixel")
        if not (-1 <= self.zncc_min < 1):
            bad(f"zncc_min={self.zncc_min} must be in [-1, 1)")
        if self.zncc_rel < 0:
            bad(f"zncc_rel={self.zncc_rel} must be >= 0 (0 disables the relative test)")
        if not (0 < self.min_component <= 1):
            bad(f"min_component={self.min_component} must be in (0, 1]")
        if self.refine is not None and self.refine not in ("light", "medium", "strong", "none"):
            bad(f"refine={self.refine!r} must be None, 'light', 'medium' or 'strong'")
        if not self.mu > 0:
            bad(f"mu={self.mu} must be > 0")
        if not self.beta > 0:
            bad(f"beta={self.beta} must be > 0")
        if self.smooth != "auto":
            ok = isinstance(self.smooth, (int, float)) and not isinstance(self.smooth, bool)
            if not (ok and self.smooth >= 0):
                bad(f"smooth={self.smooth!r} must be 'auto' or a length >= 0 in pixels")
            object.__setattr__(self, "smooth", float(self.smooth))
        if not isinstance(self.second_order_warp, bool):
            bad(f"second_order_warp={self.second_order_warp!r} must be True or False")
        if self.admm_max_iter < 1:
            bad(f"admm_max_iter={self.admm_max_iter} must be >= 1")
        if not (0 < self.admm_tol < 1):
            bad(f"admm_tol={self.admm_tol} must be in (0, 1) pixel")
        if self.n_threads is not None and self.n_threads < 1:
            bad(f"n_threads={self.n_threads} must be >= 1 or None")
        seeds = tuple((float(s[0]), float(s[1])) for s in self.seeds)
        object.__setattr__(self, "seeds", seeds)
        if self.init == "seeds" and not seeds:
            bad("init='seeds' needs at least one seed point (x, y)")

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

    def resolved_search_max(self, shape: tuple[int, int]) -> int:
        """Largest search half-range in pixels for an image of ``shape``."""
        if self.search_max is not None:
            return self.search_max
        return max(4 * self.search, max(shape) // 4)

    def replace(self, **changes: Any) -> DICParams:
        """Return a copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dictionary of the parameters."""
        d = dataclasses.asdict(self)
        d.pop("extra")
        d["seeds"] = [list(s) for s in self.seeds]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DICParams:
        """Build parameters from a dictionary, rejecting unknown keys."""
        names = {f.name for f in dataclasses.fields(cls)} - {"extra"}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(
                f"Unknown DIC parameter(s) {unknown}; valid names are {sorted(names)}"
            )
        d = dict(d)
        if "seeds" in d and d["seeds"] is not None:
            d["seeds"] = tuple(tuple(s) for s in d["seeds"])
        return cls(**d)
