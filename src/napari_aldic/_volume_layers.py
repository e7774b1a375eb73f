"""napari layer data of a volume result (issue 28), without napari itself.

``volume_layers(res)`` returns napari ``LayerDataTuple``s, ``(data, kwargs,
layer_type)``, in (z, y, x) order: Image layers of u, v, w and |u| on the
node lattice (scaled by the step, translated to the first node, so they sit
on the voxels of the volume in 3-D and in slices), the trusted displacements
as 3-D Vectors and the untrusted nodes as Points; given the strain, its von
Mises equivalent and the normal components too. The dock's "Volume (DVC)"
section adds them (``_qt/volume.py``); this module only shapes the data.
"""

from __future__ import annotations

import numpy as np

from .engine import VolumeResult, VolumeStrain

__all__ = ["volume_layers", "auto_vector_scale"]


def _lattice_geometry(res: VolumeResult):
    axes = (res.grid_zs, res.grid_ys, res.grid_xs)
    scale = tuple(float(a[1] - a[0]) if a.size > 1 else 1.0 for a in axes)
    translate = tuple(float(a[0]) for a in axes)
    return scale, translate


def auto_vector_scale(res: VolumeResult) -> float:
    """A length factor for the Vectors layer: the trusted displacements' 95th
    percentile drawn one node spacing long (1.0 when nothing moved)."""
    ok = res.valid
    mag = np.sqrt(res.u[ok] ** 2 + res.v[ok] ** 2 + res.w[ok] ** 2)
    big = float(np.percentile(mag, 95)) if mag.size else 0.0
    return min(_lattice_geometry(res)[0]) / big if big > 1e-12 else 1.0


def _strain_grids(res: VolumeResult, strain: VolumeStrain) -> dict:
    """The strain's von Mises and normal components on the lattice (NaN where untrusted)."""
    if len(strain.x) != len(res) or not np.array_equal(strain.x, res.x):
        raise ValueError("the strain is not of this volume result (other nodes)")
    out = {}
    fields = {"von Mises strain": strain.von_mises,
              **{k: strain.component(k) for k in ("exx", "eyy", "ezz")}}
    for name, values in fields.items():
        g = np.full(res.grid_shape, np.nan)
        g[res.grid_iz, res.grid_iy, res.grid_ix] = np.where(strain.valid, values, np.nan)
        out[name] = g
    return out


def volume_layers(res: VolumeResult, vector_scale: float = 1.0,
                  strain: VolumeStrain | None = None) -> list[tuple]:
    """Layer data tuples of ``res`` (see the module docstring); ``strain`` of
    :func:`~napari_aldic.engine.compute_strain_volume` adds its layers (hidden)."""
    if not isinstance(res, VolumeResult):
        raise TypeError(f"volume_layers needs a VolumeResult, not {type(res).__name__}")
    scale, translate = _lattice_geometry(res)
    layers = []
    grids = {k: res.to_grid(k) for k in ("u", "v", "w")}
    grids["|u|"] = np.sqrt(grids["u"] ** 2 + grids["v"] ** 2 + grids["w"] ** 2)
    if strain is not None:
        grids.update(_strain_grids(res, strain))
    for name, g in grids.items():
        # the components start hidden (one at a time is readable); |u| shows as a
        # translucent cloud over the volume, brightest where the motion is largest
        style = ({"rendering": "attenuated_mip", "opacity": 0.6, "blending": "additive"}
                 if name == "|u|" else {"rendering": "mip", "visible": False})
        if name not in ("u", "v", "w", "|u|"):
            style["colormap"] = "magma" if name.startswith("von") else "coolwarm"
        layers.append((g.astype(np.float32), {"name": name, "scale": scale,
                                              "translate": translate,
                                              **{"colormap": "turbo", **style}}, "image"))
    ok = res.valid
    pos = np.stack([res.z, res.y, res.x], 1)[ok]
    vec = np.stack([res.w, res.v, res.u], 1)[ok] * vector_scale
    layers.append((np.stack([pos, vec], 1), {"name": "displacement", "edge_width": 0.6,
                                             "edge_color": "white"}, "vectors"))
    bad = ~ok
    layers.append((np.stack([res.z, res.y, res.x], 1)[bad],
                   {"name": "untrusted nodes", "size": 0.5 * min(scale), "face_color": "red",
                    "border_width": 0, "features": {"reason": res.reason[bad].astype(int)}},
                   "points"))
    return layers
