"""The layers of a volume result in napari's 3-D view (issue 28): placed on the
voxels of the volume, vectors and untrusted nodes where the nodes are, and a
screenshot of it (``docs/images/volume_3d.png`` when the guide's pictures are
regenerated)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_aldic._volume_layers import volume_layers
from napari_aldic.engine import correlate_volume
from napari_aldic.engine.synthetic.volume import VolumeMotion, speckle_volume_pair

#: (nz, ny, nx): unequal sides, so that an axis swapped somewhere shows
SHAPE = (40, 48, 56)
SHIFT = (1.2, -0.4, 0.6)  # (u, v, w) voxels along x, y, z
#: stretched along x and y, squeezed along z about the centre: every component varies
MOTION = VolumeMotion.make(shift=SHIFT, strain=(0.03, 0.015, -0.02), centre=(28.0, 24.0, 20.0))


@pytest.fixture(scope="module")
def volume_result():
    ref, dfm = speckle_volume_pair(SHAPE, MOTION, seed=5)
    res = correlate_volume(ref, dfm, subset=15, step=6)
    # a corner of nodes declared untrusted, so that the Points layer has something
    corner = (res.x > 40) & (res.y < 16) & (res.z < 16)
    res.valid[corner] = False
    return ref, res


def _add(viewer, ref, res):
    viewer.add_image(ref, name="reference", colormap="gray", rendering="mip", opacity=0.5)
    added = {}
    for data, kwargs, kind in volume_layers(res, vector_scale=4.0):
        added[kwargs["name"]] = getattr(viewer, f"add_{kind}")(data, **kwargs)
    return added


def test_volume_layers_in_3d(make_napari_viewer, volume_result, save_screenshot, tmp_path,
                             keep_for_docs):
    ref, res = volume_result
    viewer = make_napari_viewer()
    layers = _add(viewer, ref, res)
    volume = viewer.layers["reference"]
    assert res.n_valid > 0.8 * len(res)
    # every lattice node (k, j, i) lies on its voxel (z, y, x) of the volume in world space
    for name in ("u", "v", "w", "|u|"):
        lay = layers[name]
        assert lay.data.shape == res.grid_shape and lay.ndim == 3
        last = np.array(res.grid_shape) - 1
        for k in (np.zeros(3, int), last, np.array([1, 2, 3])):
            world = np.asarray(lay.data_to_world(k))
            want = [res.grid_zs[k[0]], res.grid_ys[k[1]], res.grid_xs[k[2]]]
            np.testing.assert_allclose(world, want)
            np.testing.assert_allclose(volume.world_to_data(world), want)
        lo, hi = lay.extent.world
        assert np.all(lo >= -0.5) and np.all(hi <= np.array(SHAPE) - 0.5)  # inside the volume
    # u, v, w images: the exact field at their nodes (a swapped or flipped axis fails)
    zz, yy, xx = np.meshgrid(res.grid_zs, res.grid_ys, res.grid_xs, indexing="ij")
    truth = MOTION.displacement(xx, yy, zz).reshape(*zz.shape, 3)
    for c, name in enumerate("uvw"):
        err = np.abs(layers[name].data - truth[..., c])
        assert np.nanmedian(err) < 0.03 and np.ptp(truth[..., c]) > 0.3, name
    mag = np.linalg.norm(truth, axis=-1)
    assert np.nanmedian(np.abs(layers["|u|"].data - mag)) < 0.03
    # vectors: trusted nodes at (z, y, x), components (w, v, u), times the length factor
    vec = layers["displacement"].data
    ok = res.valid
    np.testing.assert_allclose(vec[:, 0], np.stack([res.z, res.y, res.x], 1)[ok])
    want = 4.0 * MOTION.displacement(res.x, res.y, res.z)[ok][:, ::-1]
    assert np.median(np.abs(vec[:, 1] - want)) < 0.1
    pts = layers["untrusted nodes"]
    np.testing.assert_allclose(pts.data, np.stack([res.z, res.y, res.x], 1)[~ok])
    assert len(pts.data) == np.count_nonzero(~ok) > 0
    # the 3-D view, tilted so that all three axes show
    assert [layers[n].visible for n in ("u", "v", "w", "|u|")] == [False] * 3 + [True]
    viewer.window.resize(1400, 900)
    viewer.dims.ndisplay = 3
    viewer.reset_view()
    viewer.scene.camera.angles = (15.0, -35.0, 130.0)
    viewer.scene.camera.zoom = 0.85 * viewer.scene.camera.zoom
    viewer.layers.selection.active = layers["|u|"]
    path = tmp_path / "volume_3d.png"
    save_screenshot(viewer, path)
    assert path.stat().st_size > 10_000
    keep_for_docs(path)
