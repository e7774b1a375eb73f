"""The napari reader: layer scale and units from the file, hyperstack channels, zarr (issue 25).

napari-free: the reader's layer data are checked as napari would receive them.
"""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
import zarr

from napari_aldic._reader import get_reader

RNG = np.random.default_rng(7)
STACK = RNG.integers(0, 255, (3, 32, 40), dtype=np.uint8)


def _layers(path):
    reader = get_reader(str(path))
    assert reader is not None, path
    return reader(str(path))


def test_ome_and_imagej_stacks_open_with_scale_and_units(tmp_path):
    ome = tmp_path / "s.ome.tif"
    tifffile.imwrite(ome, STACK, metadata={"axes": "TYX", "PhysicalSizeX": 0.65,
                                           "PhysicalSizeXUnit": "µm", "TimeIncrement": 2.0,
                                           "TimeIncrementUnit": "s"})
    ij = tmp_path / "ij.tif"
    tifffile.imwrite(ij, STACK, imagej=True, resolution=(4.0, 4.0),
                     metadata={"axes": "TYX", "unit": "um", "finterval": 2.0})
    for path, px in ((ome, 0.65), (ij, 0.25)):
        [(data, kw, kind)] = _layers(path)
        assert kind == "image" and data.shape == STACK.shape
        assert kw["scale"] == (2.0, px, px)
        assert kw["units"] == ("s", "um", "um")
        assert kw["metadata"]["units"]["pixel_size"] == px
    plain = tmp_path / "plain.tif"
    tifffile.imwrite(plain, STACK, photometric="minisblack")
    [(_, kw, _)] = _layers(plain)
    assert "scale" not in kw  # no metadata: pixels and frames


def test_hyperstack_opens_one_layer_per_channel(tmp_path):
    path = tmp_path / "hyper.tif"
    tifffile.imwrite(path, np.stack([STACK, 255 - STACK], axis=1), imagej=True,
                     metadata={"axes": "TCYX"})
    layers = _layers(path)
    assert [kw["name"] for _, kw, _ in layers] == ["hyper [channel 0]", "hyper [channel 1]"]
    np.testing.assert_array_equal(np.asarray(layers[1][0][2]), 255 - STACK[2])
    tz = tmp_path / "tz.tif"
    tifffile.imwrite(tz, np.stack([STACK, STACK], axis=1), imagej=True,
                     metadata={"axes": "TZYX"})
    assert get_reader(str(tz)) is None  # refused here; FrameSource names the axes


def test_zarr_stack_folder_opens(tmp_path):
    z = zarr.open_array(tmp_path / "s.zarr", mode="w", shape=STACK.shape, dtype=STACK.dtype)
    z[:] = STACK
    [(data, kw, _)] = _layers(tmp_path / "s.zarr")
    np.testing.assert_array_equal(np.asarray(data), STACK)
    assert kw["axis_labels"] == ("t", "y", "x")


@pytest.mark.parametrize("pattern", ["*.zarr", "*.tif"])
def test_manifest_claims_stacks_and_zarr(repo_root, pattern):
    import yaml

    doc = yaml.safe_load((repo_root / "src" / "napari_aldic" / "napari.yaml").read_text())
    [reader] = doc["contributions"]["readers"]
    assert pattern in reader["filename_patterns"] and reader["accepts_directories"]
