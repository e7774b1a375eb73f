"""Time-invariant spatial distortion of an SEM image field: calibration from
rigidly translated images and correction of measured displacements.

Convention (docs/sem.md). The distortion ``D`` is a smooth vector field on
*image* positions: the specimen (ideal, undistorted) position shown at pixel
``x`` is ``X = x - D(x)``. Two images of the same undeformed area after a
rigid stage translation ``T`` then relate a point seen at ``x0`` in the first
to ``x1 = x0 + u`` in the second by

    ``u = T + D(x0 + u) - D(x0)``                                   (1)

exactly, and linearly in ``D`` and ``T`` since ``x0`` and ``x0 + u`` are both
measured. ``D`` is a 2-D polynomial in coordinates normalised about the image
centre, with the monomials of degree 2 to ``degree``: the constant and linear
parts (an affine map) are the gauge, since a rigid translation cannot reveal
them (they only change ``T`` in (1)), and they do not bias strain. Calibration
solves (1) for the coefficients and one ``T`` per image by least squares over
the trusted nodes of every image correlated with the first, rejecting outliers
iteratively. A measurement at reference node ``x0`` with image displacement
``u`` is corrected to the specimen displacement

    ``U = (x0 + u - D(x0 + u)) - (x0 - D(x0)) = u - D(x0 + u) + D(x0)``.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.files import array_digest, atomic_write
from ..core.images import as_gray_float
from ..core.params import DICParams
from ..core.results import DICResult
from ..dic.correlate import correlate
from .positions import correct_positions

__all__ = ["DistortionModel", "calibrate_distortion", "correct_distortion", "load_distortion"]

FORMAT = "napari-aldic-sem-distortion"
VERSION = 1


class DistortionError(ValueError):
    """A calibration that cannot be made, or a model that does not fit the images."""


def _exponents(degree: int) -> list[tuple[int, int]]:
    """Monomials ``xi^i eta^j`` with ``2 <= i + j <= degree``."""
    return [(i, n - i) for n in range(2, degree + 1) for i in range(n, -1, -1)]


@dataclass
class DistortionModel:
    """A fitted distortion ``D`` (pixels) over images of ``image_shape``.

    ``coef_x``/``coef_y`` multiply the monomials of :attr:`exponents` in the
    normalised coordinates ``xi = (x - cx) / scale``, ``eta = (y - cy) /
    scale`` and give ``D`` in pixels.
    """

    degree: int
    image_shape: tuple[int, int]
    coef_x: np.ndarray
    coef_y: np.ndarray
    residual_rms: float = float("nan")
    pixel_size: float | None = None
    unit: str | None = None
    images: list = field(default_factory=list)  # [{"name", "sha256", "translation"}]
    n_nodes: int = 0

    @property
    def exponents(self) -> list[tuple[int, int]]:
        return _exponents(self.degree)

    @property
    def center(self) -> tuple[float, float]:
        return (self.image_shape[1] - 1) / 2.0, (self.image_shape[0] - 1) / 2.0

    @property
    def scale(self) -> float:
        return max(self.image_shape) / 2.0

    def basis(self, x, y) -> np.ndarray:
        """Monomials at points ``(x, y)``: shape ``(n_points, n_terms)``."""
        cx, cy = self.center
        xi = (np.ravel(np.asarray(x, float)) - cx) / self.scale
        eta = (np.ravel(np.asarray(y, float)) - cy) / self.scale
        return np.stack([xi**i * eta**j for i, j in self.exponents], axis=1)

    def displacement(self, x, y):
        """``D(x, y)`` in pixels (arrays of the shape of ``x``)."""
        shape = np.shape(x)
        B = self.basis(x, y)
        return (B @ self.coef_x).reshape(shape), (B @ self.coef_y).reshape(shape)

    def jacobian(self, x, y):
        """``dD/dx`` as ``(dDx/dx, dDx/dy, dDy/dx, dDy/dy)`` at points."""
        cx, cy = self.center
        s = self.scale
        xi = (np.ravel(np.asarray(x, float)) - cx) / s
        eta = (np.ravel(np.asarray(y, float)) - cy) / s
        bx = np.stack([i * xi ** max(i - 1, 0) * eta**j for i, j in self.exponents], 1) / s
        by = np.stack([j * xi**i * eta ** max(j - 1, 0) for i, j in self.exponents], 1) / s
        return bx @ self.coef_x, by @ self.coef_x, bx @ self.coef_y, by @ self.coef_y

    def check_shape(self, shape, what: str = "the images") -> None:
        if tuple(shape) != tuple(self.image_shape):
            raise DistortionError(
                f"the distortion calibration is for {self.image_shape[1]} x "
                f"{self.image_shape[0]} px images, {what} are {shape[1]} x {shape[0]} px: "
                "calibrate at the same magnification and resolution")

    # ------------------------------------------------------------ files
    def to_dict(self) -> dict:
        return {"format": FORMAT, "version": VERSION, "model": "polynomial",
                "degree": self.degree, "image_shape": list(self.image_shape),
                "center": list(self.center), "scale": self.scale,
                "exponents": [list(e) for e in self.exponents],
                "coef_x": [float(c) for c in self.coef_x],
                "coef_y": [float(c) for c in self.coef_y],
                "residual_rms_px": float(self.residual_rms), "n_nodes": int(self.n_nodes),
                "pixel_size": self.pixel_size, "unit": self.unit, "images": self.images,
                "convention": "specimen position X = x - D(x); D in pixels"}

    @classmethod
    def from_dict(cls, d: dict, source: str = "the distortion file") -> DistortionModel:
        if d.get("format") != FORMAT:
            raise DistortionError(f"{source} is not a napari-aldic distortion calibration "
                                  f"(format {d.get('format')!r})")
        if int(d.get("version", 0)) > VERSION:
            raise DistortionError(f"{source} has version {d['version']}, newer than this "
                                  f"napari-aldic reads ({VERSION})")
        model = cls(int(d["degree"]), tuple(int(n) for n in d["image_shape"]),
                    np.asarray(d["coef_x"], float), np.asarray(d["coef_y"], float),
                    float(d.get("residual_rms_px", np.nan)), d.get("pixel_size"),
                    d.get("unit"), list(d.get("images", [])), int(d.get("n_nodes", 0)))
        if len(model.coef_x) != len(model.exponents) or len(model.coef_y) != len(model.coef_x):
            raise DistortionError(f"{source}: {len(model.coef_x)} coefficients do not match "
                                  f"degree {model.degree}")
        return model

    def save(self, path) -> Path:
        return write_calibration(path, self.to_dict())

    def summary(self) -> dict:
        """What a result records of the model that corrected it."""
        corner = np.hypot(*self.displacement(np.array([0.0, self.image_shape[1] - 1.0]),
                                             np.array([0.0, self.image_shape[0] - 1.0])))
        return {"model": "polynomial", "degree": self.degree,
                "residual_rms_px": float(self.residual_rms),
                "max_corner_px": float(corner.max()),
                "calibration": [im.get("sha256") for im in self.images]}


def read_calibration(path, what: str) -> dict:
    """The JSON object of a calibration file (``what``: "distortion", "drift")."""
    path = Path(path).expanduser()
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DistortionError(f"{what} file {path} does not exist") from None
    except (OSError, ValueError) as exc:
        raise DistortionError(f"cannot read {what} file {path}: {exc}") from None
    if not isinstance(d, dict):
        raise DistortionError(f"{path} is not a napari-aldic {what} calibration")
    return d


def write_calibration(path, d: dict) -> Path:
    """Write a calibration's JSON object atomically."""
    path = Path(path).expanduser()
    with atomic_write(path) as tmp:
        tmp.write_text(json.dumps(d, indent=1), encoding="utf-8")
    return path


def load_distortion(path) -> DistortionModel:
    """Read a distortion calibration written by :meth:`DistortionModel.save`."""
    return DistortionModel.from_dict(read_calibration(path, "distortion"), str(path))


# ------------------------------------------------------------------ calibration
def robust_lstsq(A: np.ndarray, b: np.ndarray, rounds: int = 4, k: float = 4.0):
    """Least squares with iterative rejection of residuals beyond ``k`` robust
    standard deviations (MAD). Returns ``(solution, kept mask, rms)``."""
    keep = np.isfinite(b)
    for _ in range(rounds):
        sol = np.linalg.lstsq(A[keep], b[keep], rcond=None)[0]
        res = b - A @ sol
        sigma = 1.4826 * np.median(np.abs(res[keep] - np.median(res[keep])))
        new = np.isfinite(b) & (np.abs(res) <= k * max(sigma, 1e-6))
        if np.array_equal(new, keep):
            break
        keep = new
    res = b - A @ sol
    return sol, keep, float(np.sqrt(np.mean(res[keep] ** 2)))


def fit_distortion(pairs, image_shape, degree: int = 4) -> tuple[DistortionModel, np.ndarray]:
    """Fit (1) to measured pairs ``[(x0, y0, u, v), ...]`` (arrays of trusted
    nodes, image ``k + 1`` against image 0). Returns the model (images list
    empty) and the fitted translations ``(n_pairs, 2)``."""
    if not 2 <= degree <= 7:
        raise DistortionError(f"distortion degree {degree}: give 2 to 7 (degrees 0 and 1 are "
                              "the affine gauge; 3 to 5 suit SEM fields)")
    model = DistortionModel(degree, tuple(image_shape), np.zeros(0), np.zeros(0))
    rows_b, rows_t, b_u, b_v = [], [], [], []
    for k, (x0, y0, u, v) in enumerate(pairs):
        rows_b.append(model.basis(x0 + u, y0 + v) - model.basis(x0, y0))
        t = np.zeros((x0.size, len(pairs)))
        t[:, k] = 1.0
        rows_t.append(t)
        b_u.append(u)
        b_v.append(v)
    A = np.hstack([np.vstack(rows_b), np.vstack(rows_t)])
    nb = len(model.exponents)
    if np.linalg.matrix_rank(A[:: max(1, A.shape[0] // 4000)]) < A.shape[1]:
        raise DistortionError("the calibration translations do not determine the distortion: "
                              "translate the stage along both x and y (see docs/sem.md)")
    sx, kx, rx = robust_lstsq(A, np.concatenate(b_u))
    sy, ky, ry = robust_lstsq(A, np.concatenate(b_v))
    model.coef_x, model.coef_y = sx[:nb], sy[:nb]
    model.residual_rms = float(np.hypot(rx, ry))
    model.n_nodes = int(min(kx.sum(), ky.sum()))
    return model, np.stack([sx[nb:], sy[nb:]], axis=1)


def calibrate_distortion(images, degree: int = 4, params: DICParams | None = None,
                         names=None, pixel_size: float | None = None, unit: str | None = None,
                         progress=None) -> DistortionModel:
    """Calibrate the spatial distortion from images of one undeformed area after
    rigid stage translations of unknown amount (image 0 is the reference).

    Each image is correlated with image 0 (``correlate`` with ``params``; its
    search range is widened to the largest translation found by phase
    correlation), and (1) is solved over all trusted nodes.
    """
    images = [as_gray_float(im, f"calibration image {k}") for k, im in enumerate(images)]
    if len(images) < 3:
        raise DistortionError(f"{len(images)} calibration image(s): give at least 3 (the "
                              "reference and translations along x and y; 8 recommended)")
    shape = images[0].shape
    for k, im in enumerate(images):
        if im.shape != shape:
            raise DistortionError(f"calibration image {k} is {im.shape[1]} x {im.shape[0]} px, "
                                  f"image 0 is {shape[1]} x {shape[0]} px")
    params = params or DICParams()
    pairs = []
    for k in range(1, len(images)):
        if progress is not None:
            progress((k - 1) / (len(images) - 1), f"calibration image {k}")
        res = correlate(images[0], images[k], params=_searching(params, images[0], images[k]))
        ok = res.valid & np.isfinite(res.u) & np.isfinite(res.v)
        if ok.sum() < 20:
            raise DistortionError(f"calibration image {k}: only {int(ok.sum())} trusted nodes "
                                  "against image 0; is it the same area, moved by under "
                                  "a fifth of the field of view?")
        pairs.append((res.x[ok], res.y[ok], res.u[ok], res.v[ok]))
    model, trans = fit_distortion(pairs, shape, degree)
    names = list(names) if names is not None else [f"image {k}" for k in range(len(images))]
    model.images = [{"name": str(names[k]), "sha256": array_digest(im),
                     "translation_px": [0.0, 0.0] if k == 0 else [float(t) for t in trans[k - 1]]}
                    for k, im in enumerate(images)]
    model.pixel_size, model.unit = pixel_size, unit
    return model


def _searching(params: DICParams, f: np.ndarray, g: np.ndarray) -> DICParams:
    """``params`` with a search range that covers the pair's rigid shift."""
    from scipy import fft as sfft

    F = sfft.rfft2(f - f.mean())
    G = sfft.rfft2(g - g.mean())
    R = F.conj() * G
    corr = sfft.irfft2(R / np.maximum(np.abs(R), 1e-12), s=f.shape)
    iy, ix = np.unravel_index(int(np.argmax(corr)), corr.shape)
    dy = iy - f.shape[0] if iy > f.shape[0] // 2 else iy
    dx = ix - f.shape[1] if ix > f.shape[1] // 2 else ix
    need = int(max(abs(dx), abs(dy))) + 8
    if need <= params.search:
        return params
    return dataclasses.replace(params, search=need, search_max=max(need, params.search_max or 0))


# ------------------------------------------------------------------ correction
def correct_distortion(result: DICResult, model: DistortionModel) -> DICResult:
    """``result`` with displacements (and subset gradients) in undistorted
    specimen coordinates: ``U = u - D(x + u) + D(x)`` at every node. Node
    positions stay the reference image's pixels ``(x, y)``; the specimen point
    of a node is ``(x, y) - D(x, y)`` (under a pixel of the gauge's choice).
    Returns a new result; ``meta["sem"]["distortion"]`` records the model."""
    model.check_shape(result.image_shape, "the analysed images")
    if result.meta.get("sem", {}).get("distortion") is not None:
        raise DistortionError("this result is already corrected for distortion")
    out = correct_positions(result, model, model)
    out.meta.setdefault("sem", {})["distortion"] = model.summary()
    return out
