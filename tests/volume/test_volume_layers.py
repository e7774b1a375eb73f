"""Layer data of a volume result (issue 28): shapes, placement, no napari needed."""

from __future__ import annotations

import numpy as np
import pytest

from napari_aldic._volume_layers import auto_vector_scale, volume_layers
from napari_aldic.engine import compute_strain_volume, correlate_volume
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


def test_strain_layers_and_vector_length():
    motion = VolumeMotion.make(strain=(0.02, 0.0, -0.01), centre=(20.0, 20.0, 20.0))
    ref, dfm = speckle_volume_pair((40, 40, 40), motion, seed=3)
    res = correlate_volume(ref, dfm, subset=21, step=6)
    strain = compute_strain_volume(res, measure="infinitesimal")
    layers = {kw["name"]: (data, kw) for data, kw, _ in volume_layers(res, strain=strain)}
    for name, want in (("exx", 0.02), ("eyy", 0.0), ("ezz", -0.01)):
        data, kw = layers[name]
        assert data.shape == res.grid_shape and kw["visible"] is False
        assert abs(np.nanmedian(data) - want) < 1e-3, name
    assert kw["scale"] == layers["u"][1]["scale"] and kw["translate"] == layers["u"][1]["translate"]
    # u grows along x (axis 2 of the lattice): the strain grid is not transposed
    assert np.nanmedian(np.diff(layers["u"][0], axis=2)) > 0.1
    # the 95th percentile of |u| is drawn one node spacing (6 voxels) long
    k = auto_vector_scale(res)
    mag = np.sqrt(res.u ** 2 + res.v ** 2 + res.w ** 2)[res.valid]
    assert np.isclose(np.percentile(mag, 95) * k, 6.0)
    other = correlate_volume(ref, dfm, subset=21, step=8)
    with pytest.raises(ValueError, match="not of this volume result"):
        volume_layers(other, strain=strain)
