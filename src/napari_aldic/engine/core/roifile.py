"""ROI files of run folders: one bit-packed copy of a run's ROI, named by its
content, that the run's result files refer to."""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np

from .files import array_digest, atomic_write

ROI_FORMAT = "napari-aldic-roi"


def write_roi_file(folder, roi) -> dict:
    """Store ``roi`` once in ``folder`` as ``roi_<digest>.npz`` (bit-packed;
    named by its content, so an existing file is reused) and return the
    reference a result file keeps instead of its own copy:
    ``{"file": name, "sha256": digest}``."""
    roi = np.asarray(roi, bool)
    digest = array_digest(roi)
    path = Path(folder) / f"roi_{digest[:16]}.npz"
    if not path.is_file():
        head = json.dumps({"format": ROI_FORMAT, "sha256": digest, "shape": list(roi.shape)})
        with atomic_write(path) as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(fh, header=np.array(head), roi_packed=np.packbits(roi, axis=None))
    return {"file": path.name, "sha256": digest}


def read_roi_file(path, digest: str, shape) -> np.ndarray:
    """The ROI stored by :func:`write_roi_file` (read-only; results of one run
    share one array). Raises ``ValueError`` naming the file when it is
    missing, unreadable or not the ROI ``digest`` the result refers to."""
    path = Path(path)
    try:
        st = path.stat()
    except OSError:
        raise ValueError(f"the ROI file {path} that this result refers to is missing; keep "
                         f"result files together with the roi_*.npz files of their run "
                         "folder") from None
    return _read_roi(str(path), st.st_mtime_ns, st.st_size, digest, tuple(shape))


@lru_cache(maxsize=4)
def _read_roi(path: str, mtime_ns: int, size: int, digest: str, shape: tuple) -> np.ndarray:
    try:
        with np.load(path, allow_pickle=False) as z:
            bits = np.unpackbits(z["roi_packed"], count=int(np.prod(shape)))
        roi = bits.reshape(shape).astype(bool)
    except Exception as exc:  # any damage: the file is named below
        raise ValueError(f"cannot read the ROI file {path}: {exc}") from None
    if array_digest(roi) != digest:
        raise ValueError(f"the ROI file {path} does not hold the ROI its results were "
                         "computed with (damaged or replaced)")
    roi.flags.writeable = False
    return roi
