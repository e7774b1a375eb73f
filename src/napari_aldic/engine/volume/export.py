"""Volume results out: MAT, VTU (hexahedra, for ParaView/meshio) and CSV.

(NPZ is :meth:`~..core.volresults.VolumeResult.save`.) Every file gets the
node coordinates (voxels), u, v, w, validity, reason, ZNCC and, when a
:class:`~.strain.VolumeStrain` is given, its six tensor components,
principal strains and von Mises strain. Written atomically.
"""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np

from ..core.files import atomic_write
from ..core.volresults import VolumeResult
from .grid import VolumeGrid
from .hexmesh import hex_elements
from .strain import COMPONENTS, VolumeStrain

__all__ = ["export_volume", "volume_columns"]

_VTK_HEXAHEDRON = 12


def volume_columns(res: VolumeResult, strain: VolumeStrain | None = None) -> dict:
    """Per-node columns, in file order."""
    cols = {k: np.asarray(getattr(res, k), float) for k in ("x", "y", "z", "u", "v", "w")}
    cols["valid"] = res.valid.astype(np.int8)
    cols["reason"] = res.reason.astype(np.int8)
    cols["zncc"] = np.asarray(res.zncc, float)
    for k in ("u_std", "v_std", "w_std"):
        if getattr(res, k) is not None:
            cols[k] = np.asarray(getattr(res, k), float)
    if strain is not None:
        for c in COMPONENTS:
            cols[c] = strain.component(c)
        for i in range(3):
            cols[f"e{i + 1}"] = strain.principal[:, i]
        cols["von_mises"] = strain.von_mises
        cols["strain_valid"] = strain.valid.astype(np.int8)
    return cols


def _b64(arr: np.ndarray) -> str:
    raw = np.ascontiguousarray(arr).tobytes()
    return base64.b64encode(np.uint32(len(raw)).tobytes() + raw).decode("ascii")


_TYPES = {np.dtype(np.float64): "Float64", np.dtype(np.int64): "Int64",
          np.dtype(np.int8): "Int8", np.dtype(np.uint8): "UInt8"}


def _array(name, arr, ncomp=1) -> str:
    arr = np.asarray(arr)
    attr = f' Name="{name}"' if name else ""
    return (f'<DataArray type="{_TYPES[arr.dtype]}"{attr} NumberOfComponents="{ncomp}" '
            f'format="binary">{_b64(arr)}</DataArray>\n')


def _vtu_text(res: VolumeResult, cols: dict) -> str:
    grid = VolumeGrid(res.grid_xs, res.grid_ys, res.grid_zs, res.grid_ix, res.grid_iy,
                      res.grid_iz)
    el = hex_elements(grid).astype(np.int64)
    pts = np.stack([res.x, res.y, res.z], 1).astype(np.float64)
    data = "".join(_array(k, np.asarray(v)) for k, v in cols.items() if k not in "xyz")
    data += _array("displacement", np.stack([res.u, res.v, res.w], 1).astype(float), 3)
    return (
        '<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="1.0" '
        'byte_order="LittleEndian" header_type="UInt32">\n<UnstructuredGrid>\n'
        f'<Piece NumberOfPoints="{len(pts)}" NumberOfCells="{len(el)}">\n'
        f'<PointData>\n{data}</PointData>\n<Points>\n{_array(None, pts, 3)}</Points>\n'
        f'<Cells>\n{_array("connectivity", el.ravel())}'
        f'{_array("offsets", 8 * np.arange(1, len(el) + 1, dtype=np.int64))}'
        f'{_array("types", np.full(len(el), _VTK_HEXAHEDRON, np.uint8))}</Cells>\n'
        '</Piece>\n</UnstructuredGrid>\n</VTKFile>\n')


def export_volume(res: VolumeResult, path, strain: VolumeStrain | None = None) -> Path:
    """Write ``res`` (and ``strain``) to ``path``: ``.mat``, ``.vtu`` or ``.csv``.

    Raises ``ValueError`` for another suffix, ``FileNotFoundError`` for a
    missing folder.
    """
    path = Path(path)
    kind = path.suffix.lower()
    if kind not in (".mat", ".vtu", ".csv"):
        raise ValueError(f"{path}: volume results export to .mat, .vtu or .csv "
                         "(.npz: VolumeResult.save)")
    if not path.parent.exists():
        raise FileNotFoundError(f"folder {path.parent} does not exist; create it first")
    cols = volume_columns(res, strain)
    with atomic_write(path) as tmp:
        if kind == ".mat":
            from scipy.io import savemat
            savemat(tmp, {**cols, "volume_shape": np.array(res.volume_shape),
                          "subset": res.params.subset, "step": res.params.step},
                    do_compression=True)
        elif kind == ".vtu":
            Path(tmp).write_text(_vtu_text(res, cols), encoding="ascii")
        else:
            np.savetxt(tmp, np.stack(list(cols.values()), 1), delimiter=",",
                       header=",".join(cols), comments="", fmt="%.10g")
    return path
