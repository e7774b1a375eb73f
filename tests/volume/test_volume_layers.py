"""Layer data of a volume result (issue 28): shapes, placement, no napari needed."""

from __future__ import annotations

import numpy as np

from napari_aldic._volume_layers import volume_layers
from napari_aldic.engine import correlate_volume
from napari_aldic.engine.synthetic.volume import VolumeMotion, speckle_volume_pair


def test_layers_sit_on_the_voxels_of_the_volume():
    ref, dfm = speckle_volume_pair((40, 40, 40), VolumeMotion.make(shift=(1.2, -0.4, 0.3)),
                                   seed=8)
    res = correlate_volume(ref, dfm, subset=21, step=8)
    res.valid[0] = False  # one untrusted node
    layers = {kw["name"]: (data, kw, kind) for data, kw, kind in volume_layers(res)}
    u, kw, kind = layers["u"]
    assert kind == "image" and u.shape == res.grid_shape
    # lattice index k along an axis lands on voxel translate + k * scale
    assert kw["translate"] == (11.0, 11.0, 11.0) and kw["scale"] == (8.0, 8.0, 8.0)
    assert np.isnan(u[0, 0, 0]) and np.isclose(np.nanmean(u), np.mean(res.u[res.valid]), rtol=1e-6)
    vec = layers["displacement"][0]
    assert vec.shape == (len(res) - 1, 2, 3)
    np.testing.assert_allclose(vec[:, 1].mean(0), [0.3, -0.4, 1.2], atol=0.01)  # (w, v, u)
    pts = layers["untrusted nodes"][0]
    np.testing.assert_array_equal(pts, [[res.z[0], res.y[0], res.x[0]]])
