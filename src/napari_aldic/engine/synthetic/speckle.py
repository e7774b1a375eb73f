"""Synthetic speckle images with exact ground truth.

The speckle pattern is analytic: a smooth saturation of a sum of isotropic
Gaussian blobs, ``I(X) = lo + (hi - lo) * (1 - exp(-sum_k a_k exp(-|X - X_k|^2
/ (2 s_k^2))))``. A camera pixel integrates light over its area, so every pixel
value is the mean of ``I`` over the pixel square, computed with tensor-product
Gauss-Legendre quadrature. The deformed image is rendered the same way in the
deformed configuration: each quadrature point ``x`` is mapped back to the
reference point ``X = phi^{-1}(x)`` of the displacement field (``x = X + u(X)``,
Lagrangian) and the analytic pattern is evaluated there. No image is ever
interpolated, so the displacement field is the exact truth up to the
quadrature error (~1e-6 grey levels for the default speckle sizes).

Displacement fields: :class:`Translation`, :class:`Affine` (uniform strain,
rotation, any constant gradient), :class:`Rotation`, :class:`Sinusoid`,
:class:`ModeICrack` (LEFM near-tip field, discontinuous across the crack).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..kernels.speckle import speckle_intensity

__all__ = [
    "SpecklePattern",
    "make_pattern",
    "render",
    "speckle_pair",
    "DisplacementField",
    "Translation",
    "Affine",
    "Rotation",
    "Sinusoid",
    "ModeICrack",
    "PlateWithHole",
    "Sum",
]


# ---------------------------------------------------------------- fields
class DisplacementField:
    """Lagrangian displacement ``u(X)``: material point X moves to X + u(X)."""

    def displacement(self, X, Y):  # pragma: no cover - interface
        raise NotImplementedError

    def gradient(self, X, Y, eps: float = 1e-4):
        """``(du/dx, du/dy, dv/dx, dv/dy)`` at reference points (central differences)."""
        X = np.asarray(X, float)
        Y = np.asarray(Y, float)
        up, vp = self.displacement(X + eps, Y)
        um, vm = self.displacement(X - eps, Y)
        uq, vq = self.displacement(X, Y + eps)
        un, vn = self.displacement(X, Y - eps)
        return ((up - um) / (2 * eps), (uq - un) / (2 * eps),
                (vp - vm) / (2 * eps), (vq - vn) / (2 * eps))

    def inverse(self, x, y, iters: int = 60, tol: float = 1e-10):
        """Reference points ``X`` with ``X + u(X) = x``; NaN where none exists.

        Fixed-point iteration ``X <- x - u(X)``, which converges when the
        displacement gradient is small (< 1); points that do not converge
        (e.g. inside an opened crack) have no material and are returned as NaN.
        """
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        X, Y = x.copy().ravel(), y.copy().ravel()
        xf, yf = x.ravel(), y.ravel()
        todo = np.arange(X.size)  # iterate only the points still moving
        for _ in range(iters):
            if todo.size == 0:
                break
            u, v = self.displacement(X[todo], Y[todo])
            Xn, Yn = xf[todo] - u, yf[todo] - v
            moving = (np.abs(Xn - X[todo]) + np.abs(Yn - Y[todo])) >= tol
            X[todo], Y[todo] = Xn, Yn
            todo = todo[moving]
        X, Y = X.reshape(x.shape), Y.reshape(x.shape)
        u, v = self.displacement(X, Y)
        # no preimage (e.g. inside an opened crack): the iteration oscillates
        bad = np.hypot(X + u - x, Y + v - y) > 1e-6
        X = np.where(bad, np.nan, X)
        Y = np.where(bad, np.nan, Y)
        return X, Y


@dataclass
class Translation(DisplacementField):
    """Rigid translation by ``(u, v)`` pixels."""

    u: float = 0.0
    v: float = 0.0

    def displacement(self, X, Y):
        X = np.asarray(X, float)
        return np.full_like(X, self.u), np.full_like(X, self.v)

    def gradient(self, X, Y, eps=None):
        z = np.zeros_like(np.asarray(X, float))
        return z, z.copy(), z.copy(), z.copy()

    def inverse(self, x, y, iters=None, tol=None):
        return np.asarray(x, float) - self.u, np.asarray(y, float) - self.v


@dataclass
class Affine(DisplacementField):
    """Constant displacement gradient: ``u(X) = t + G (X - c)``.

    ``G = [[du/dx, du/dy], [dv/dx, dv/dy]]``; ``c`` is the centre in pixels.
    """

    G: tuple = ((0.0, 0.0), (0.0, 0.0))
    center: tuple = (0.0, 0.0)
    t: tuple = (0.0, 0.0)

    def displacement(self, X, Y):
        G = np.asarray(self.G, float)
        dX = np.asarray(X, float) - self.center[0]
        dY = np.asarray(Y, float) - self.center[1]
        return (self.t[0] + G[0, 0] * dX + G[0, 1] * dY,
                self.t[1] + G[1, 0] * dX + G[1, 1] * dY)

    def gradient(self, X, Y, eps=None):
        G = np.asarray(self.G, float)
        o = np.ones_like(np.asarray(X, float))
        return G[0, 0] * o, G[0, 1] * o, G[1, 0] * o, G[1, 1] * o

    def inverse(self, x, y, iters=None, tol=None):
        A = np.eye(2) + np.asarray(self.G, float)
        Ai = np.linalg.inv(A)
        bx = np.asarray(x, float) - self.center[0] - self.t[0]
        by = np.asarray(y, float) - self.center[1] - self.t[1]
        return (self.center[0] + Ai[0, 0] * bx + Ai[0, 1] * by,
                self.center[1] + Ai[1, 0] * bx + Ai[1, 1] * by)

    @classmethod
    def strain_rotation(cls, exx=0.0, eyy=0.0, exy=0.0, angle_deg=0.0,
                        center=(0.0, 0.0), t=(0.0, 0.0)) -> Affine:
        """Stretch ``diag(1+exx, 1+eyy)`` with tensor shear ``exy``, then rotate.

        The deformation gradient is ``R(angle) @ (I + E)``; the displacement
        gradient ``G = F - I``. Angle in degrees, counter-clockwise in the
        usual x-right/y-up sense is clockwise on screen (y points down).
        """
        a = np.deg2rad(angle_deg)
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        U = np.array([[1 + exx, exy], [exy, 1 + eyy]])
        G = R @ U - np.eye(2)
        return cls(G=tuple(map(tuple, G)), center=tuple(center), t=tuple(t))


def Rotation(angle_deg: float, center=(0.0, 0.0)) -> Affine:
    """Rigid rotation by ``angle_deg`` degrees about ``center``."""
    return Affine.strain_rotation(angle_deg=angle_deg, center=center)


@dataclass
class Sinusoid(DisplacementField):
    """``u = au sin(2 pi X / wavelength + phase)``, ``v = av sin(2 pi Y / wavelength + phase)``.

    With ``along="x"`` both components vary along X; with ``"y"`` along Y;
    with ``"xy"`` (default) u varies along X and v along Y.
    """

    amplitude_u: float = 0.5
    amplitude_v: float = 0.5
    wavelength: float = 128.0
    phase: float = 0.0
    along: str = "xy"

    def displacement(self, X, Y):
        X = np.asarray(X, float)
        Y = np.asarray(Y, float)
        k = 2 * np.pi / self.wavelength
        su = X if self.along in ("x", "xy") else Y
        sv = Y if self.along in ("y", "xy") else X
        return (self.amplitude_u * np.sin(k * su + self.phase),
                self.amplitude_v * np.sin(k * sv + self.phase))


def _polar(X, Y, centre) -> tuple[np.ndarray, np.ndarray]:
    """Polar coordinates ``(r, theta)`` of reference points about ``centre``
    (theta from +x towards +y, in ``(-pi, pi]``)."""
    dX = np.asarray(X, float) - centre[0]
    dY = np.asarray(Y, float) - centre[1]
    return np.hypot(dX, dY), np.arctan2(dY, dX)


def _kolosov(nu: float) -> float:
    """Kolosov constant of plane stress, ``kappa = (3 - nu) / (1 + nu)``."""
    return (3 - nu) / (1 + nu)


@dataclass
class ModeICrack(DisplacementField):
    """Mode-I LEFM near-tip displacement field around a straight crack.

    The crack runs from the left edge along ``y = tip[1]`` to the tip at
    ``tip`` (pixels). With polar coordinates ``(r, theta)`` about the tip
    (theta = 0 ahead of the crack, y down on screen):

    ``u = A sqrt(r) cos(theta/2) (kappa - 1 + 2 sin^2(theta/2))``
    ``v = A sqrt(r) sin(theta/2) (kappa + 1 - 2 cos^2(theta/2))``

    with ``A = K_I / (2 mu sqrt(2 pi))`` given directly as ``amplitude`` in
    px^(1/2), and ``kappa = (3 - nu) / (1 + nu)`` (plane stress). ``v`` jumps
    across the crack faces (theta = +-pi): the opening at distance r behind
    the tip is ``2 A sqrt(r) (kappa + 1)``. A rigid translation ``t`` may be
    added.
    """

    tip: tuple = (128.0, 128.0)
    amplitude: float = 0.05
    nu: float = 0.3
    t: tuple = (0.0, 0.0)

    def displacement(self, X, Y):
        r, th = _polar(X, Y, self.tip)
        kappa = _kolosov(self.nu)
        a = self.amplitude * np.sqrt(r)
        u = a * np.cos(th / 2) * (kappa - 1 + 2 * np.sin(th / 2) ** 2)
        v = a * np.sin(th / 2) * (kappa + 1 - 2 * np.cos(th / 2) ** 2)
        return u + self.t[0], v + self.t[1]

    def opening(self, X) -> np.ndarray:
        """Crack opening (v jump, pixels) at abscissa X behind the tip."""
        r = np.maximum(self.tip[0] - np.asarray(X, float), 0.0)
        return 2 * self.amplitude * np.sqrt(r) * (_kolosov(self.nu) + 1)


@dataclass
class PlateWithHole(DisplacementField):
    """Kirsch field: an infinite plate with a circular hole under uniaxial
    tension along x (plane stress), plus an optional translation ``t``.

    With polar coordinates ``(r, theta)`` about ``center``, hole radius ``a``
    (pixels), ``A = S / (4 mu)`` (``amplitude``: remote stress over four times
    the shear modulus) and ``kappa = (3 - nu) / (1 + nu)``:

    ``u_r = A [r ((kappa - 1)/2 + cos 2t) + a^2/r (1 + (1 + kappa) cos 2t) - a^4/r^3 cos 2t]``
    ``u_t = A [(1 - kappa) a^2/r - r - a^4/r^3] sin 2t``

    Far from the hole this is uniform strain ``exx = A (kappa + 1) / 2``,
    ``eyy = A (kappa - 3) / 2``. There is no material inside the hole: the
    deformed image shows the background there.
    """

    center: tuple = (128.0, 128.0)
    radius: float = 30.0
    amplitude: float = 0.004
    nu: float = 0.3
    t: tuple = (0.0, 0.0)

    def displacement(self, X, Y):
        r, th = _polar(X, Y, self.center)
        r = np.maximum(r, 1e-9)
        a, A = self.radius, self.amplitude
        kappa = _kolosov(self.nu)
        c2, s2 = np.cos(2 * th), np.sin(2 * th)
        ur = A * (r * ((kappa - 1) / 2 + c2) + a**2 / r * (1 + (1 + kappa) * c2)
                  - a**4 / r**3 * c2)
        ut = A * ((1 - kappa) * a**2 / r - r - a**4 / r**3) * s2
        u = ur * np.cos(th) - ut * np.sin(th)
        v = ur * np.sin(th) + ut * np.cos(th)
        return u + self.t[0], v + self.t[1]

    def inverse(self, x, y, iters: int = 60, tol: float = 1e-10):
        X, Y = super().inverse(x, y, iters, tol)
        hole = np.hypot(X - self.center[0], Y - self.center[1]) < self.radius
        return np.where(hole, np.nan, X), np.where(hole, np.nan, Y)

    def roi(self, shape) -> np.ndarray:
        """Reference-image ROI: True outside the hole."""
        yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
        return np.hypot(xx - self.center[0], yy - self.center[1]) > self.radius


@dataclass
class Sum(DisplacementField):
    """Sum of displacement fields (e.g. uniform strain + sinusoid)."""

    fields: list = field(default_factory=list)

    def displacement(self, X, Y):
        u = np.zeros_like(np.asarray(X, float))
        v = np.zeros_like(u)
        for f in self.fields:
            a, b = f.displacement(X, Y)
            u = u + a
            v = v + b
        return u, v


# ---------------------------------------------------------------- pattern
@dataclass
class SpecklePattern:
    """Analytic speckle pattern: Gaussian blobs in reference coordinates."""

    x: np.ndarray
    y: np.ndarray
    sigma: np.ndarray
    amp: np.ndarray
    lo: float = 20.0
    hi: float = 235.0
    bin_size: float = 8.0
    # CSR index of blobs by spatial bin (built by make_pattern)
    bins_start: np.ndarray = None
    bins_order: np.ndarray = None
    origin: tuple = (0.0, 0.0)
    nbins: tuple = (0, 0)


def make_pattern(shape, speckle_radius: float = 2.0, density: float = 0.5,
                 seed: int | None = 0, margin: float = 64.0,
                 lo: float = 20.0, hi: float = 235.0) -> SpecklePattern:
    """Random speckle pattern covering ``shape`` plus ``margin`` pixels.

    Parameters
    ----------
    shape : (rows, cols)
        Image size the pattern must cover.
    speckle_radius : float
        Mean Gaussian blob standard deviation in pixels (drawn uniformly in
        [0.7, 1.3] times this value). Speckles of about 3-5 px diameter, as
        good-practice guides recommend, correspond to radii ~1.5-2.5.
    density : float
        Blob centres per area ``(2 * speckle_radius)^2``; 0.5 gives about
        half coverage.
    seed : int or None
        Random seed (same seed, same pattern).
    margin : float
        Extra border in pixels so material moving into view is textured.
    lo, hi : float
        Grey levels of the background and of saturated speckles.
    """
    rng = np.random.default_rng(seed)
    h, w = shape
    x0, y0 = -margin, -margin
    W, H = w + 2 * margin, h + 2 * margin
    n = int(density * W * H / (2 * speckle_radius) ** 2)
    x = rng.uniform(x0, x0 + W, n)
    y = rng.uniform(y0, y0 + H, n)
    sigma = speckle_radius * rng.uniform(0.7, 1.3, n)
    amp = rng.uniform(0.6, 1.4, n)
    bin_size = float(4.0 * sigma.max())
    nbx = int(np.ceil(W / bin_size)) + 1
    nby = int(np.ceil(H / bin_size)) + 1
    bx = np.floor((x - x0) / bin_size).astype(np.int64)
    by = np.floor((y - y0) / bin_size).astype(np.int64)
    b = by * nbx + bx
    order = np.argsort(b, kind="stable")
    counts = np.bincount(b, minlength=nbx * nby)
    start = np.zeros(nbx * nby + 1, np.int64)
    np.cumsum(counts, out=start[1:])
    return SpecklePattern(x[order], y[order], sigma[order], amp[order], lo, hi,
                          bin_size, start, np.arange(n, dtype=np.int64),
                          (x0, y0), (nbx, nby))


def _gauss_legendre(n: int):
    t, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * t, 0.5 * w  # on [-0.5, 0.5], weights sum to 1


def render(pattern: SpecklePattern, shape, displacement: DisplacementField | None = None,
           n_quad: int = 4, noise: float = 0.0, bit_depth: int | None = 8,
           seed: int | None = None, background: float | None = None,
           rows_per_tile: int = 128) -> np.ndarray:
    """Render the pattern as seen after ``displacement`` (None = reference).

    Each pixel is the area mean of the analytic intensity over its square,
    by ``n_quad x n_quad`` Gauss-Legendre points mapped through the inverse
    displacement map. Gaussian noise of standard deviation ``noise`` grey
    levels is added, then values are rounded and clipped to ``bit_depth``
    bits (``None`` keeps float64). Points with no material (an opened crack)
    take the ``background`` grey level (default: the pattern's ``lo``).
    """
    h, w = shape
    t, wq = _gauss_legendre(n_quad)
    out = np.empty((h, w), np.float64)
    bg = pattern.lo if background is None else background
    for r0 in range(0, h, rows_per_tile):
        r1 = min(h, r0 + rows_per_tile)
        yy, xx = np.mgrid[r0:r1, 0:w].astype(np.float64)
        acc = np.zeros((r1 - r0, w))
        for a in range(n_quad):
            for b in range(n_quad):
                xq = xx + t[b]
                yq = yy + t[a]
                if displacement is None:
                    Xq, Yq = xq, yq
                else:
                    Xq, Yq = displacement.inverse(xq, yq)
                val = np.empty(xq.size)
                speckle_intensity(np.ascontiguousarray(Xq, float).ravel(),
                                  np.ascontiguousarray(Yq, float).ravel(),
                                  pattern.x, pattern.y, pattern.sigma, pattern.amp,
                                  pattern.bins_start, pattern.origin[0], pattern.origin[1],
                                  pattern.bin_size, pattern.nbins[0], pattern.nbins[1],
                                  pattern.lo, pattern.hi, val)
                val = np.where(np.isnan(val), bg, val)
                acc += wq[a] * wq[b] * val.reshape(xq.shape)
        out[r0:r1] = acc
    if noise > 0:
        out += np.random.default_rng(seed).normal(0.0, noise, out.shape)
    if bit_depth is None:
        return out
    top = 2**bit_depth - 1
    dtype = np.uint8 if bit_depth <= 8 else np.uint16
    if bit_depth > 8 and pattern.hi <= 255:
        out = out * (top / 255.0)  # use the full 16-bit range
    return np.clip(np.rint(out), 0, top).astype(dtype)


def speckle_pair(shape=(256, 256), displacement: DisplacementField | None = None,
                 noise: float = 0.0, speckle_radius: float = 2.0, density: float = 0.5,
                 seed: int = 0, bit_depth: int | None = 8, n_quad: int = 4,
                 margin: float = 64.0):
    """Reference and deformed images of one pattern with exact truth.

    Independent noise (``noise`` grey levels, standard deviation) is added to
    each image. ``margin`` (pixels) is how far beyond the image the pattern
    extends, so material moving into view is textured: make it larger than the
    largest displacement. Returns ``(reference, deformed)``.
    """
    pat = make_pattern(shape, speckle_radius=speckle_radius, density=density, seed=seed,
                       margin=margin)
    ref = render(pat, shape, None, n_quad=n_quad, noise=noise, bit_depth=bit_depth,
                 seed=None if seed is None else seed + 1)
    dfm = render(pat, shape, displacement, n_quad=n_quad, noise=noise,
                 bit_depth=bit_depth, seed=None if seed is None else seed + 2)
    return ref, dfm
