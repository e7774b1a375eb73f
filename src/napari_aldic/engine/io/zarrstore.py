"""The stacked field store of a run folder: ``fields.zarr``.

``track(out_dir=...)`` writes each finished frame twice: its exact result
file ``frame_#####.npz`` (every node, quadtree nodes included, and the full
metadata: the record that ``load_run``, exports and resuming read), and one
slice of this chunked zarr store, so that a long sequence can be read field
by field, frame range by frame range, without loading result files:

* ``u``, ``v``, ``dudx``, ``dudy``, ``dvdx``, ``dvdy``, ``zncc`` -- float64,
  shape ``(T, ny, nx)`` on the node lattice (rows = y; ``T`` analysed
  frames, in the order of ``attrs["frames"]``), one chunk per frame (frames
  finishing in any order never share a chunk); untrusted nodes keep their
  values, see ``valid``;
* ``valid`` (bool) and ``reason`` (int8, :class:`~napari_aldic.engine.Reason`
  codes; -1 where no node is), same shape;
* per-frame metadata, shape ``(T,)``: ``done`` (bool), ``frame`` and
  ``reference_frame`` (int32, -1 until done), ``n_valid`` (int64), and the
  size and modification time of the frame's result file (``file_size``,
  ``file_mtime_ns``), which let a resumed run trust a finished frame
  without reading its file;
* ``attrs``: ``format`` ("napari-aldic-fields"), ``format_version``,
  ``run_id`` (as in ``sequence.json``), ``frames``, ``grid_xs``, ``grid_ys``.

Open it with ``zarr.open_group(folder / "fields.zarr", mode="r")`` or
:func:`open_fields`.
"""

from __future__ import annotations

import os
import secrets
import shutil
from pathlib import Path

import numpy as np

__all__ = ["FieldStore", "open_fields", "STORE_NAME", "STORE_FIELDS"]

STORE_NAME = "fields.zarr"
STORE_FORMAT = "napari-aldic-fields"
STORE_VERSION = 1
#: the node fields stored as (T, ny, nx) float64 arrays
STORE_FIELDS = ("u", "v", "dudx", "dudy", "dvdx", "dvdy", "zncc")
_PER_FRAME = {"done": (bool, False), "frame": ("int32", -1), "reference_frame": ("int32", -1),
              "n_valid": ("int64", 0), "file_size": ("int64", -1),
              "file_mtime_ns": ("int64", -1)}


def open_fields(folder):
    """The ``fields.zarr`` group of run ``folder``, read-only."""
    import zarr

    path = Path(os.fspath(folder)).expanduser() / STORE_NAME
    if not path.is_dir():
        raise FileNotFoundError(f"no field store at {path}")
    return zarr.open_group(str(path), mode="r")


class FieldStore:
    """Writer of a run folder's ``fields.zarr`` (one process writes it, under
    the run folder's lock).

    The frame result files are the record; the store is derived from them.
    A new store is built under a temporary name and renamed into place, so a
    run killed while creating it leaves no half store. A store that cannot
    be used as it is (killed mid-write, an array missing, a damaged chunk, or
    written for other frames) is built again and refilled from the frame
    files (:attr:`rebuilt`; :meth:`trusted` then trusts no frame). A link or
    a file in its place is refused before anything is written: nothing is
    written through a link.

    Parameters
    ----------
    folder : Path
        The run folder.
    run_id : str
        The run's identity digest.
    frames : list of int
        The analysed frame numbers (``T = len(frames)``).
    grid_xs, grid_ys : array
        The node lattice (of frame 0's result).
    """

    def __init__(self, folder: Path, run_id: str, frames: list[int], grid_xs, grid_ys):
        self.path = Path(folder) / STORE_NAME
        self.frames = list(frames)
        self.grid_shape = (len(grid_ys), len(grid_xs))
        self.attrs = {"format": STORE_FORMAT, "format_version": STORE_VERSION,
                      "run_id": run_id, "frames": self.frames,
                      "grid_xs": [float(x) for x in grid_xs],
                      "grid_ys": [float(y) for y in grid_ys]}
        if os.path.islink(self.path) or (os.path.lexists(self.path)
                                         and not self.path.is_dir()):
            raise ValueError(f"{self.path} is a link or a file, not the run's field store; "
                             "nothing is written through it. Remove it and run again")
        self.rebuilt = False
        self.group = self._open() if self.path.is_dir() else None
        if self.group is None:
            self.rebuilt = os.path.lexists(self.path)
            self.group = self._create()

    def _shapes(self) -> dict:
        t, (ny, nx) = len(self.frames), self.grid_shape
        out = {name: ((t, ny, nx), np.dtype("float64")) for name in STORE_FIELDS}
        out["valid"] = ((t, ny, nx), np.dtype(bool))
        out["reason"] = ((t, ny, nx), np.dtype("int8"))
        out.update({name: ((t,), np.dtype(dtype)) for name, (dtype, _) in _PER_FRAME.items()})
        return out

    def _open(self):
        """The existing store if it is this run's and whole, else None."""
        import zarr

        for root, dirs, names in os.walk(self.path):  # a planted link: never written through
            if any(os.path.islink(os.path.join(root, n)) for n in (*dirs, *names)):
                return None
        try:
            group = zarr.open_group(str(self.path), mode="r+")
            if dict(group.attrs) != self.attrs:
                return None
            for name, (shape, dtype) in self._shapes().items():
                arr = group[name]
                if tuple(arr.shape) != shape or np.dtype(arr.dtype) != dtype:
                    return None
            for name in _PER_FRAME:  # read: a damaged chunk here is found now
                np.asarray(group[name][:])
        except Exception:  # any damage: the store is built again from the frame files
            return None
        return group

    def _create(self):
        """A new, empty store: built beside, then renamed into place."""
        import zarr

        tmp = self.path.with_name(f".{STORE_NAME}.{secrets.token_hex(4)}.part")
        group = zarr.open_group(str(tmp), mode="w")
        group.attrs.update(self.attrs)
        fills = {"valid": False, "reason": -1}
        fills.update({name: fill for name, (_, fill) in _PER_FRAME.items()})
        for name, (shape, dtype) in self._shapes().items():
            chunks = (1,) + shape[1:] if len(shape) == 3 else (min(shape[0], 4096),)
            group.create_array(name, shape=shape, chunks=chunks, dtype=dtype,
                               fill_value=fills.get(name, np.nan))
        if os.path.lexists(self.path):  # a damaged store of this run: replaced
            aside = self.path.with_name(f".{STORE_NAME}.{secrets.token_hex(4)}.old.part")
            os.rename(self.path, aside)
            shutil.rmtree(aside, ignore_errors=True)
        os.rename(tmp, self.path)
        return zarr.open_group(str(self.path), mode="r+")

    def extend(self, frames: list[int], run_id: str) -> None:
        """Grow the store to the analysed ``frames`` (the old ones first, as
        before) of a run whose identity is now ``run_id`` (``watch``: frames
        are added as they arrive); the new frames are not done."""
        frames = list(frames)
        if frames[:len(self.frames)] != self.frames:
            raise ValueError(f"{self.path}: frames {frames} do not extend {self.frames}")
        n = len(frames)
        for name in STORE_FIELDS + ("valid", "reason"):
            self.group[name].resize((n,) + self.grid_shape)
        for name in _PER_FRAME:
            self.group[name].resize((n,))
        self.frames = frames
        self.group.attrs.update({"run_id": run_id, "frames": frames})

    def write(self, i: int, res) -> None:
        """Write the fields of ``frames[i]`` (its result ``res``); call
        :meth:`mark_done` once its result file is on disk."""
        if tuple(res.grid_shape) != self.grid_shape:
            raise ValueError(f"frame {self.frames[i]} has a node lattice of shape "
                             f"{tuple(res.grid_shape)}, the field store {self.grid_shape}")
        self.group["done"][i] = False  # until mark_done: the slices are being replaced
        for name in STORE_FIELDS:
            self.group[name][i] = res.to_grid(name, invalid=None)
        on = res.grid_ix >= 0
        for name, values, fill in (("valid", res.valid, False), ("reason", res.reason, -1)):
            grid = np.full(self.grid_shape, fill, dtype=np.asarray(values).dtype)
            grid[res.grid_iy[on], res.grid_ix[on]] = np.asarray(values)[on]
            self.group[name][i] = grid

    def mark_done(self, i: int, res, file: Path | None) -> None:
        """Record frame ``frames[i]`` as finished (and its result file's size
        and modification time)."""
        st = os.stat(file) if file is not None else None
        self.group["frame"][i] = self.frames[i]
        self.group["reference_frame"][i] = int(res.meta.get("reference_frame", 0))
        self.group["n_valid"][i] = int(res.n_valid)
        self.group["file_size"][i] = st.st_size if st else -1
        self.group["file_mtime_ns"][i] = st.st_mtime_ns if st else -1
        self.group["done"][i] = True

    def trusted(self) -> np.ndarray:
        """Per analysed frame: finished in the store, its result file the one
        written then (same size and modification time), and its slices
        readable (a damaged chunk makes the frame be written again)."""
        done = np.asarray(self.group["done"][:])
        size = np.asarray(self.group["file_size"][:])
        mtime = np.asarray(self.group["file_mtime_ns"][:])
        ok = np.zeros(len(self.frames), bool)
        for i in np.nonzero(done)[0]:
            try:
                st = os.stat(self.path.parent / f"frame_{self.frames[i]:05d}.npz")
                if st.st_size != size[i] or st.st_mtime_ns != mtime[i]:
                    continue
                for name in (*STORE_FIELDS, "valid", "reason"):
                    self.group[name][i]
            except Exception:  # missing file, damaged chunk
                continue
            ok[i] = True
        return ok
