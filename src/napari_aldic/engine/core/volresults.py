"""Result of a DVC analysis of one volume pair, with save/load (no pickle).

The file is the same kind of ``.npz`` as a 2-D result (a JSON header plus
one array per node field, written atomically, read defensively with the
array headers checked first) under its own ``format`` name, so
:func:`~.results.load_result` tells the two apart by the header.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .files import atomic_write
from .npzfile import MAX_IMAGE_SIDE, npz_headers
from .params import DICParams
from .reasons import Reason

__all__ = ["VolumeResult", "load_volume_result", "is_volume_file", "VOLUME_FORMAT"]

VOLUME_FORMAT = "napari-aldic-volume-result"
_VERSION = 1
_GRAD = ("dudx", "dudy", "dudz", "dvdx", "dvdy", "dvdz", "dwdx", "dwdy", "dwdz")
_ARRAYS = ("x", "y", "z", "u", "v", "w", *_GRAD, "valid", "zncc", "reason", "iterations",
           "grid_ix", "grid_iy", "grid_iz", "grid_xs", "grid_ys", "grid_zs")
_OPTIONAL = ("u_local", "v_local", "w_local", "u_std", "v_std", "w_std", "elements")
_LATTICE = {"grid_xs": 2, "grid_ys": 1, "grid_zs": 0}  # axis of volume_shape bounding each


@dataclass
class VolumeResult:
    """Displacements at the nodes of one reference/deformed volume pair.

    Coordinates and displacements are in voxels of the reference volume
    (``x`` = axis 2, ``y`` = axis 1, ``z`` = axis 0; voxel centres at
    integers); displacement is Lagrangian: the material point at
    ``(x, y, z)`` is at ``(x + u, y + v, z + w)`` in the deformed volume.

    Attributes
    ----------
    x, y, z, u, v, w : (n,) float64
    dudx ... dwdz : (n,) float64
        Displacement gradient of each subset's affine warp (:attr:`F`).
    valid : (n,) bool
        Trusted (``reason == 0``).
    zncc : (n,) float64
    reason : (n,) int8
        :class:`~.reasons.Reason` per node.
    iterations : (n,) int32
    grid_ix, grid_iy, grid_iz : (n,) int64, and grid_xs, grid_ys, grid_zs
        Lattice indices of the nodes and the lattice coordinates.
    volume_shape : (nz, ny, nx)
    params : DICParams (lengths in voxels)
    meta : dict
        Versions, timing, ADMM history.
    u_local, v_local, w_local : AL-DVC's last subset displacements (or None)
    u_std, v_std, w_std : predicted standard uncertainty (voxels) or None
    elements : (E, 8) int64 or None
        Trilinear hexahedra of the AL-DVC mesh (VTK node order).
    roi : (nz, ny, nx) bool or None (stored bit-packed)
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    u: np.ndarray
    v: np.ndarray
    w: np.ndarray
    dudx: np.ndarray
    dudy: np.ndarray
    dudz: np.ndarray
    dvdx: np.ndarray
    dvdy: np.ndarray
    dvdz: np.ndarray
    dwdx: np.ndarray
    dwdy: np.ndarray
    dwdz: np.ndarray
    valid: np.ndarray
    zncc: np.ndarray
    reason: np.ndarray
    iterations: np.ndarray
    grid_ix: np.ndarray
    grid_iy: np.ndarray
    grid_iz: np.ndarray
    grid_xs: np.ndarray
    grid_ys: np.ndarray
    grid_zs: np.ndarray
    volume_shape: tuple[int, int, int]
    params: DICParams
    meta: dict[str, Any] = field(default_factory=dict)
    u_local: np.ndarray | None = None
    v_local: np.ndarray | None = None
    w_local: np.ndarray | None = None
    u_std: np.ndarray | None = None
    v_std: np.ndarray | None = None
    w_std: np.ndarray | None = None
    elements: np.ndarray | None = None
    roi: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.x.size)

    @property
    def n_valid(self) -> int:
        return int(np.count_nonzero(self.valid))

    @property
    def F(self) -> np.ndarray:
        """Displacement gradient per node, (n, 3, 3): row = component (u, v, w),
        column = derivative (x, y, z)."""
        return np.stack([getattr(self, k) for k in _GRAD], -1).reshape(-1, 3, 3)

    @property
    def grid_shape(self) -> tuple[int, int, int]:
        return (self.grid_zs.size, self.grid_ys.size, self.grid_xs.size)

    def to_grid(self, name: str = "u", invalid=np.nan) -> np.ndarray:
        """Field ``name`` on the (z, y, x) node lattice; ``invalid`` where no
        trusted node is (``invalid=None`` keeps untrusted values)."""
        out = np.full(self.grid_shape, np.nan)
        out[self.grid_iz, self.grid_iy, self.grid_ix] = np.asarray(getattr(self, name), float)
        if invalid is not None:
            bad = np.ones(self.grid_shape, bool)
            bad[self.grid_iz, self.grid_iy, self.grid_ix] = ~self.valid
            out[bad] = invalid
        return out

    def reason_counts(self) -> dict[str, int]:
        codes, counts = np.unique(self.reason, return_counts=True)
        return {Reason.describe(c): int(k) for c, k in zip(codes, counts)}

    def summary(self) -> str:
        """A short text summary."""
        v = self.valid
        lines = [f"{len(self)} nodes ({self.n_valid} valid) in a "
                 f"{' x '.join(map(str, self.volume_shape))} volume (z, y, x), subset "
                 f"{self.params.subset} voxels, step {self.params.step}, "
                 f"method {self.params.method}"]
        if v.any():
            lines.append("; ".join(f"{k}: mean {getattr(self, k)[v].mean():+.4f}"
                                   for k in ("u", "v", "w")) + " voxels")
        t = self.meta.get("timing", {})
        if "total" in t:
            lines.append(f"time {t['total']:.2f} s ({len(self) / max(t['total'], 1e-9):,.0f} "
                         "POI/s)")
        flagged = {k: c for k, c in self.reason_counts().items() if k != "converged"}
        if flagged:
            lines.append("flagged: " + ", ".join(f"{k}: {c}" for k, c in flagged.items()))
        return "\n".join(lines)

    def save(self, path) -> Path:
        """Write to ``path`` (``.npz``, atomically; see :meth:`DICResult.save`)."""
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_suffix(".npz")
        if not path.parent.exists():
            raise FileNotFoundError(f"folder {path.parent} does not exist; create it first")
        header = {"format": VOLUME_FORMAT, "format_version": _VERSION,
                  "volume_shape": [int(s) for s in self.volume_shape],
                  "params": self.params.to_dict(), "meta": self.meta}
        arrays = {k: np.asarray(getattr(self, k)) for k in _ARRAYS}
        arrays.update({k: np.asarray(getattr(self, k)) for k in _OPTIONAL
                       if getattr(self, k) is not None})
        if self.roi is not None:
            arrays["roi_packed"] = np.packbits(np.asarray(self.roi, bool), axis=None)
        with atomic_write(path) as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(fh, header=np.array(json.dumps(header)), **arrays)
        return path

    @classmethod
    def load(cls, path) -> VolumeResult:
        return load_volume_result(path)


def _fail(path, problem: str) -> ValueError:
    return ValueError(f"cannot read volume result file {path}: {problem}")


def _header(path: Path) -> dict | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            return json.loads(str(z["header"])) if "header" in z.files else None
    except (ValueError, OSError, EOFError, zlib.error, zipfile.BadZipFile):
        return None


def is_volume_file(path) -> bool:
    """True when ``path`` is a readable ``.npz`` whose header names a volume result."""
    path = Path(path)
    try:
        heads = npz_headers(path)
    except (ValueError, OSError):
        return False
    head = _header(path) if "header" in heads and heads["header"][0] == () else None
    return isinstance(head, dict) and head.get("format") == VOLUME_FORMAT


def _check(path: Path, heads: dict, shape) -> None:
    missing = [k for k in _ARRAYS if k not in heads]
    if missing:
        raise _fail(path, f"the file is incomplete: array(s) {missing} are missing")
    n = heads["x"][0][0] if len(heads["x"][0]) == 1 else -1
    if n < 0 or n > int(np.prod(shape)):
        raise _fail(path, f"array 'x' has shape {heads['x'][0]}; expected one value per node")
    for k in [k for k in (*_ARRAYS, *_OPTIONAL) if k in heads]:
        k_shape, dtype = heads[k]
        if dtype.kind not in "biuf":
            raise _fail(path, f"array {k!r} has dtype {dtype}; expected numbers")
        if k in _LATTICE:
            ok = len(k_shape) == 1 and k_shape[0] <= shape[_LATTICE[k]]
        elif k == "elements":
            ok = len(k_shape) == 2 and k_shape[1] == 8 and k_shape[0] <= 8 * max(n, 1)
        else:
            ok = k_shape == (n,)
        if not ok:
            raise _fail(path, f"array {k!r} has shape {k_shape}, impossible for {n} nodes in a "
                              f"{shape} volume (damaged or edited file)")
    if "roi_packed" in heads and heads["roi_packed"][0] != ((int(np.prod(shape)) + 7) // 8,):
        raise _fail(path, "its ROI does not match volume_shape in its header")


def load_volume_result(path) -> VolumeResult:
    """Read a file written by :meth:`VolumeResult.save`; ``ValueError`` naming
    the file for anything damaged, inconsistent or not a volume result."""
    path = Path(path)
    heads = npz_headers(path)
    head = _header(path)
    if not isinstance(head, dict) or head.get("format") != VOLUME_FORMAT:
        raise _fail(path, "it is not a napari-aldic volume result (no or wrong header)")
    shape = head.get("volume_shape")
    if not (isinstance(shape, list) and len(shape) == 3 and all(
            isinstance(s, int) and 1 <= s <= MAX_IMAGE_SIDE for s in shape)):
        raise _fail(path, f"volume_shape {shape!r} in its header is not three whole numbers")
    shape = tuple(shape)
    _check(path, heads, shape)
    try:
        params = DICParams.from_dict(head.get("params") or {})
    except (TypeError, ValueError) as exc:
        raise _fail(path, f"the parameters in its header are invalid: {exc}") from None
    names = [k for k in (*_ARRAYS, *_OPTIONAL, "roi_packed") if k in heads]
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in names}
    except (ValueError, OSError, EOFError, zlib.error, zipfile.BadZipFile) as exc:
        raise _fail(path, f"an array is damaged ({exc})") from None
    packed = arrays.pop("roi_packed", None)
    if packed is not None:
        arrays["roi"] = np.unpackbits(packed, count=int(np.prod(shape))).reshape(shape) > 0
    meta = head.get("meta") if isinstance(head.get("meta"), dict) else {}
    return VolumeResult(**arrays, volume_shape=shape, params=params, meta=meta)
