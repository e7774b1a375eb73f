"""napari layer data of a volume result (issue 28), without napari itself.

``volume_layers(res)`` returns napari ``LayerDataTuple``s, ``(data, kwargs,
layer_type)``, in (z, y, x) order: Image layers of u, v, w and |u| on the
node lattice (scaled by the step, translated to the first node, so they sit
on the voxels of the volume in 3-D and in slices), the trusted displacements
as 3-D Vectors and the untrusted nodes as Points. The dock's "volume" switch
will add them; this module only shapes the data.
"""

from __future__ import annotations

import numpy as np

from .engine import VolumeResult

__all__ = ["volume_layers", "vector_scale"]


def _lattice_geometry(res: VolumeResult):
    axes = (res.grid_zs, res.grid_ys, res.grid_xs)
    scale = tuple(float(a[1] - a[0]) if a.size > 1 else 1.0 for a in axes)
    translate = tuple(float(a[0]) for a in axes)
    return scale, translate


def vector_scale(res: VolumeResult) -> float:
    """A length factor for the Vectors layer: the trusted displacements' 95th
    percentile drawn one node spacing long (1.0 when nothing moved)."""
    ok = res.valid
    mag = np.sqrt(res.u[ok] ** 2 + res.v[ok] ** 2 + res.w[ok] ** 2)
    big = float(np.percentile(mag, 95)) if mag.size else 0.0
    return min(_lattice_geometry(res)[0]) / big if big > 1e-12 else 1.0


def volume_layers(res: VolumeResult, vector_scale: float = 1.0) -> list[tuple]:
    """Layer data tuples of ``res`` (see the module docstring)."""
    if not isinstance(res, VolumeResult):
        raise TypeError(f"volume_layers needs a VolumeResult, not {type(res).__name__}")
    scale, translate = _lattice_geometry(res)
    layers = []
    grids = {k: res.to_grid(k) for k in ("u", "v", "w")}
    grids["|u|"] = np.sqrt(grids["u"] ** 2 + grids["v"] ** 2 + grids["w"] ** 2)
    for name, g in grids.items():
        # the components start hidden (one at a time is readable); |u| shows as a
        # translucent cloud over the volume, brightest where the motion is largest
        style = ({"rendering": "attenuated_mip", "opacity": 0.6, "blending": "additive"}
                 if name == "|u|" else {"rendering": "mip", "visible": False})
        layers.append((g.astype(np.float32), {"name": name, "scale": scale,
                                              "translate": translate, "colormap": "turbo",
                                              **style}, "image"))
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
