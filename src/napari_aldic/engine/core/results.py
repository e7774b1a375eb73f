"""Result of a DIC analysis of one image pair, with save/load (no pickle)."""

from __future__ import annotations

import json
import operator
import threading
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .files import atomic_write, check_folder, file_above
from .npzfile import read_result_npz
from .params import DICParams
from .reasons import Reason
from .roifile import read_roi_file
from .volresults import VolumeResult, is_volume_file, load_volume_result

__all__ = ["DICResult", "load_result"]

_FORMAT = "napari-aldic-result"
_FORMAT_VERSION = 1
_ARRAYS = ("x", "y", "u", "v", "dudx", "dudy", "dvdx", "dvdy", "valid", "zncc",
           "reason", "iterations", "grid_ix", "grid_iy", "grid_xs", "grid_ys")
_OPTIONAL = ("u_local", "v_local", "u_std", "v_std", "sssig", "mig", "elements", "hanging")


@dataclass
class DICResult:
    """Displacements at the nodes of one reference/deformed pair.

    Coordinates and displacements are in pixels of the reference image
    (x = column, y = row; pixel centres at integers); displacement is
    Lagrangian: the material point at ``(x, y)`` in the reference image is at
    ``(x + u, y + v)`` in the deformed image.

    Attributes
    ----------
    x, y : (n,) float64
        Node coordinates.
    u, v : (n,) float64
        Displacement along x and y.
    dudx, dudy, dvdx, dvdy : (n,) float64
        Displacement gradient of each subset's affine shape function (stacked
        as :attr:`F`; the deformation gradient is ``I + F``).
    valid : (n,) bool
        Node converged and is trusted (``reason == 0``).
    zncc : (n,) float64
        Zero-normalised cross-correlation of the matched subset (1 = perfect).
    reason : (n,) int8
        :class:`~napari_aldic.engine.core.reasons.Reason` code per node.
    iterations : (n,) int32
        IC-GN iterations used.
    grid_ix, grid_iy : (n,) int64
        Lattice indices of the nodes (-1 for quadtree nodes off the base
        lattice); ``grid_xs``/``grid_ys`` give the lattice.
    image_shape : (rows, cols)
    params : DICParams
    meta : dict
        Software versions, timing (seconds per stage), ADMM history.
    u_local, v_local : (n,) float64 or None
        For ``method="aldic"``: the last local (subset) displacements, kept
        for inspection; ``u``/``v`` are then the compatible global field.
    u_std, v_std : (n,) float64 or None
        Predicted standard uncertainty of the subset displacement at each node
        (pixels; for AL-DIC of ``u_local``/``v_local``, an upper bound of the
        smoothed ``u``/``v``), from the subset's Gauss-Newton matrix and its
        correlation residual (``dic.quality``, checked against Monte-Carlo);
        a node whose larger value exceeds ``params.max_uncertainty`` is
        flagged ``UNCERTAIN`` (by ``dic.reliability``'s older estimate). NaN
        where the subset did not converge.
    sssig, mig : (n,) float64 or None
        Speckle quality of each reference subset: the smaller of the sums of
        squared intensity gradients ``Σ f_x²``, ``Σ f_y²`` (grey levels²;
        Pan et al. 2008) and the mean intensity gradient (grey levels/px).
    elements : (E, 4) int64 or None
        Q4 elements (corner node indices) of the AL-DIC / quadtree mesh.
    hanging : (H, 3) int64 or None
        Hanging-node constraints ``(h, a, b)``: ``u[h] = (u[a] + u[b]) / 2``.
    roi : (H, W) bool or None
        The region of interest analysed (stored bit-packed in files).
    """

    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    dudx: np.ndarray
    dudy: np.ndarray
    dvdx: np.ndarray
    dvdy: np.ndarray
    valid: np.ndarray
    zncc: np.ndarray
    reason: np.ndarray
    iterations: np.ndarray
    grid_ix: np.ndarray
    grid_iy: np.ndarray
    grid_xs: np.ndarray
    grid_ys: np.ndarray
    image_shape: tuple[int, int]
    params: DICParams
    meta: dict[str, Any] = field(default_factory=dict)
    u_local: np.ndarray | None = None
    v_local: np.ndarray | None = None
    u_std: np.ndarray | None = None
    v_std: np.ndarray | None = None
    sssig: np.ndarray | None = None
    mig: np.ndarray | None = None
    elements: np.ndarray | None = None
    hanging: np.ndarray | None = None
    roi: np.ndarray | None = None

    # ------------------------------------------------------------- views
    def __len__(self) -> int:
        return int(self.x.size)

    @property
    def n_valid(self) -> int:
        return int(np.count_nonzero(self.valid))

    @property
    def F(self) -> np.ndarray:
        """Displacement gradient per node, shape (n, 2, 2): [[du/dx, du/dy], [dv/dx, dv/dy]].

        Not the deformation gradient despite the letter: that is ``I + F``.
        """
        return np.stack([np.stack([self.dudx, self.dudy], -1),
                         np.stack([self.dvdx, self.dvdy], -1)], -2)

    @property
    def grid_shape(self) -> tuple[int, int]:
        return (self.grid_ys.size, self.grid_xs.size)

    def to_grid(self, name: str = "u", invalid=np.nan) -> np.ndarray:
        """Field ``name`` on the node lattice (rows = y), ``invalid`` where no
        trusted node is (use ``invalid=None`` to keep untrusted values)."""
        vals = np.asarray(getattr(self, name), dtype=np.float64)
        out = np.full(self.grid_shape, np.nan)
        on = self.grid_ix >= 0  # quadtree nodes off the lattice are skipped
        out[self.grid_iy[on], self.grid_ix[on]] = vals[on]
        if invalid is not None:
            bad = np.ones(self.grid_shape, bool)
            bad[self.grid_iy[on], self.grid_ix[on]] = ~self.valid[on]
            out[bad] = invalid
        return out

    def reason_counts(self) -> dict[str, int]:
        """Number of nodes per reason (text)."""
        codes, counts = np.unique(self.reason, return_counts=True)
        return {Reason.describe(c): int(k) for c, k in zip(codes, counts)}

    def aldic_summary(self) -> str | None:
        """One line on the AL-DIC regularisation and iterations (None for Local DIC)."""
        reg = self.meta.get("regularisation")
        if not reg:
            return None
        hist = self.meta.get("admm_history") or []
        how = "chosen from the noise" if reg.get("mode") == "auto" else "fixed"
        warp = "second-order" if reg.get("second_order_warp") else "affine"
        taken = hist[-1].get("local_predicted", 0) if hist else 0
        return (f"AL-DIC: smoothing length {reg['smooth_px']:.1f} px ({how}), {warp} "
                f"subset warp, {len(hist)} ADMM iterations"
                + (f"; last local step: {taken} nodes took their linear prediction "
                   "(no IC-GN iteration)" if taken else ""))

    def summary(self) -> str:
        """A short text summary."""
        v = self.valid
        lines = [
            f"{len(self)} nodes ({self.n_valid} valid), subset {self.params.subset} px, "
            f"step {self.params.step} px, method {self.params.method}",
        ]
        if v.any():
            u, w = self.u[v], self.v[v]
            lines.append(
                f"u: mean {u.mean():+.4f} px [{u.min():+.3f}, {u.max():+.3f}]; "
                f"v: mean {w.mean():+.4f} px [{w.min():+.3f}, {w.max():+.3f}]; "
                f"median ZNCC {np.median(self.zncc[v]):.4f}"
            )
        if self.aldic_summary():
            lines.append(self.aldic_summary())
        conv = self.meta.get("convergence")
        if conv:
            med = conv.get("median_iterations")
            lines.append(("IC-GN: " if med is None else f"IC-GN: median {med:g} iterations, ")
                         + f"{conv['at_cap']} nodes at the cap of {conv['max_iter']}")
        t = self.meta.get("timing", {})
        if "total" in t:
            secs = t.get("analysis", t["total"])  # Numba's first-run compile apart
            rate = len(self) / max(secs, 1e-9)
            lines.append(f"time {secs:.3f} s ({rate:,.0f} POI/s)"
                         + (f" + {t['compile']:.1f} s compiling kernels (first run)"
                            if t.get("compile", 0.0) >= 0.05 else ""))
        flagged = {k: c for k, c in self.reason_counts().items() if k != "converged"}
        if flagged:
            lines.append("flagged: " + ", ".join(f"{k}: {c}" for k, c in flagged.items()))
        return "\n".join(lines)

    # ------------------------------------------------------------- I/O
    def save(self, path, *, roi_file: dict | None = None) -> Path:
        """Write the result to ``path`` (``.npz``, no pickled objects).

        The ROI is stored bit-packed in the file, unless ``roi_file`` (the
        reference :func:`~napari_aldic.engine.core.files.write_roi_file`
        returns: the run folder's ``roi_<digest>.npz`` beside ``path``) is
        given: frames of one run then share that one copy.

        The file is written under a temporary name and renamed when complete
        (:func:`~napari_aldic.engine.core.files.atomic_write`), so an
        interrupted save never leaves a truncated file behind. A missing
        folder raises :class:`FileNotFoundError`; other write failures raise
        :class:`~napari_aldic.engine.core.files.ExportError` (an ``OSError``)
        that names the file and the cause.
        """
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_suffix(".npz")
        if file_above(path.parent) is not None:
            check_folder(path)  # names the file that stands where a folder should be
        if not path.parent.exists():
            raise FileNotFoundError(f"folder {path.parent} does not exist; create it first")
        header = {
            "format": _FORMAT,
            "format_version": _FORMAT_VERSION,
            "image_shape": list(self.image_shape),
            "params": self.params.to_dict(),
            "meta": self.meta,
        }
        arrays = {k: np.asarray(getattr(self, k)) for k in _ARRAYS}
        for k in _OPTIONAL:
            if getattr(self, k) is not None:
                arrays[k] = np.asarray(getattr(self, k))
        if self.roi is not None and roi_file is not None:
            header["roi_file"] = {"file": roi_file["file"], "sha256": roi_file["sha256"]}
        elif self.roi is not None:
            arrays["roi_packed"] = np.packbits(np.asarray(self.roi, bool), axis=None)
        with atomic_write(path) as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(fh, header=np.array(json.dumps(header)), **arrays)
        return path

    @classmethod
    def load(cls, path) -> DICResult:
        """Read a result written by :meth:`save`."""
        return load_result(path)


def load_result(path) -> DICResult | VolumeResult:
    """Read a ``.npz`` result written by :meth:`DICResult.save` (or, for a
    volume, by :meth:`~.volresults.VolumeResult.save`: a ``VolumeResult``).

    The file's structure is checked from its array headers before anything
    is decompressed (:func:`~napari_aldic.engine.core.npzfile.read_result_npz`):
    an empty, truncated, damaged, inconsistent or oversized file, or one that
    is not a result, raises ``ValueError`` naming the file and the problem.
    """
    path = Path(path)
    if is_volume_file(path):
        return load_volume_result(path)
    header, arrays = read_result_npz(path, _FORMAT, _ARRAYS, _OPTIONAL)
    ref = header.get("roi_file")
    if isinstance(ref, dict):  # the run folder's one copy of the ROI
        arrays["roi"] = read_roi_file(path.parent / Path(str(ref.get("file"))).name,
                                      str(ref.get("sha256")), tuple(header["image_shape"]))
    return DICResult(**arrays, image_shape=header["image_shape"], params=header["params"],
                     meta=header["meta"])


class LazyFrames(Sequence):
    """The frames of a run folder, each read from its file when asked for.

    A read-only sequence of ``DICResult`` (``None`` for a frame not on disk),
    so a finished run of thousands of frames can be read and exported with
    memory flat in the number of frames: indexing (an int, negative too, or
    a slice, which gives a list) reads the file; iterating reads one frame at
    a time. Only the last ``keep`` frames read stay in memory (a consecutive
    pair, e.g. a frame and the one before it for velocities, is read once).
    :attr:`present` tells which frames exist without reading any.
    """

    def __init__(self, paths, keep: int = 2):
        self.paths = tuple(None if p is None else Path(p) for p in paths)
        self.keep = max(int(keep), 1)
        self._recent: OrderedDict[int, DICResult] = OrderedDict()
        self._lock = threading.Lock()

    @property
    def present(self) -> tuple[bool, ...]:
        """Per frame: True where its result file is there (nothing is read)."""
        return tuple(p is not None for p in self.paths)

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        i = operator.index(k)
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(f"frame position {k} out of range for {len(self)} frames")
        if self.paths[i] is None:
            return None
        with self._lock:
            hit = self._recent.get(i)
            if hit is not None:
                self._recent.move_to_end(i)
                return hit
        res = load_result(self.paths[i])
        with self._lock:
            self._recent[i] = res
            while len(self._recent) > self.keep:
                self._recent.popitem(last=False)
        return res

    def __iter__(self) -> Iterator[DICResult | None]:
        for i in range(len(self)):
            yield self[i]

    def __repr__(self) -> str:
        return f"LazyFrames({len(self)} frames, {sum(self.present)} on disk)"

    def __getstate__(self):  # the cache and the lock stay behind (e.g. when pickled)
        return {"paths": self.paths, "keep": self.keep}

    def __setstate__(self, state):
        self.__init__(state["paths"], state["keep"])


@dataclass
class SequenceResult:
    """Per-frame results, all in frame-0 (Lagrangian) coordinates.

    ``seq[0]`` is the reference frame (zero displacement); ``seq[k]`` is frame
    k against frame 0. Frames not computed (cancelled run) are ``None``.
    ``frames`` is a list, or for a run read back from its folder
    (:func:`~napari_aldic.engine.io.load_run`) a :class:`LazyFrames` that
    reads each frame when it is used.
    """

    frames: Sequence
    params: DICParams
    reference: str
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, k: int) -> DICResult | None:
        return self.frames[k]

    @property
    def complete(self) -> bool:
        present = getattr(self.frames, "present", None)  # LazyFrames: no frame is read
        if present is not None:
            return all(present)
        return all(r is not None for r in self.frames)
