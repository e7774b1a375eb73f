"""Pixel size and frame interval of stacks, hyperstack axes, zarr stacks (issue 25)."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
import zarr

from napari_aldic.engine import synthetic
from napari_aldic.engine.io import ChannelChoiceError, FrameSource, open_stack

SHAPE = (64, 64)


@pytest.fixture(scope="module")
def stack() -> np.ndarray:
    ref, d1 = synthetic.speckle_pair(SHAPE, synthetic.Translation(0.4, -0.2), seed=3)
    _, d2 = synthetic.speckle_pair(SHAPE, synthetic.Translation(0.8, -0.4), seed=3)
    return np.stack([ref, d1, d2])


def _ome(path, stack):
    tifffile.imwrite(path, stack, metadata={
        "axes": "TYX", "PhysicalSizeX": 0.65, "PhysicalSizeXUnit": "µm",
        "PhysicalSizeY": 0.65, "TimeIncrement": 2.0, "TimeIncrementUnit": "s"})
    return path


def _imagej(path, stack):
    tifffile.imwrite(path, stack, imagej=True, resolution=(4.0, 4.0),
                     metadata={"axes": "TYX", "unit": "um", "finterval": 2.0})
    return path


def test_ome_and_imagej_stacks_carry_pixel_size_and_interval(tmp_path, stack):
    ome = FrameSource(_ome(tmp_path / "s.ome.tif", stack))
    ij = FrameSource(_imagej(tmp_path / "ij.tif", stack))
    assert (ome.units.pixel_size, ome.units.unit, ome.units.frame_interval) == (0.65, "um", 2.0)
    assert (ij.units.pixel_size, ij.units.unit, ij.units.frame_interval) == (0.25, "um", 2.0)
    assert ome.units_source == {"pixel_size": "OME-XML metadata of s.ome.tif",
                                "frame_interval": "OME-XML metadata of s.ome.tif"}
    assert ij.units_source["frame_interval"] == "ImageJ metadata of ij.tif"
    assert FrameSource(stack).units is None  # arrays record nothing


def test_folder_of_tiffs_takes_the_first_images_pixel_size(tmp_path, stack):
    for k, img in enumerate(stack):
        tifffile.imwrite(tmp_path / f"img_{k}.tif", img, resolution=(1 / 2e-4, 1 / 2e-4),
                         resolutionunit="CENTIMETER")
    src = FrameSource(tmp_path)
    assert src.units.unit == "um" and src.units.pixel_size == pytest.approx(2.0)
    assert src.units_source["pixel_size"].startswith("TIFF resolution")


def test_hyperstack_channels_are_refused_or_chosen(tmp_path, stack):
    hyper = np.stack([stack, stack[:, ::-1]], axis=1)  # T=3, C=2
    path = tmp_path / "hyper.tif"
    tifffile.imwrite(path, hyper, imagej=True, metadata={"axes": "TCYX"})
    with pytest.raises(ChannelChoiceError, match=r"hyper\.tif has axes TCYX .*2 channels"
                                                 r".*--channel") as err:
        FrameSource(path)
    assert err.value.n_channels == 2
    src = FrameSource(path, channel=1)
    assert len(src) == 3 and src.axes == "TCYX"
    for k in range(3):
        np.testing.assert_array_equal(src[k], stack[k, ::-1])
    with pytest.raises(ValueError, match="channel 2 is out of range"):
        FrameSource(path, channel=2)
    with pytest.raises(ValueError, match="no channel axis"):
        FrameSource(stack, channel=0)


def test_time_and_depth_together_are_refused(tmp_path, stack):
    path = tmp_path / "tz.tif"
    tifffile.imwrite(path, np.stack([stack, stack], axis=1), imagej=True,
                     metadata={"axes": "TZYX"})
    with pytest.raises(ValueError, match=r"tz\.tif has axes TZYX.*T \(time, 3\) and Z "
                                         r"\(depth, 2\)"):
        FrameSource(path)


def test_zarr_and_ome_zarr_stacks(tmp_path, stack):
    z = zarr.open_array(tmp_path / "s.zarr", mode="w", shape=stack.shape, dtype=stack.dtype,
                        chunks=(1, *SHAPE))
    z[:] = stack
    src = open_stack(tmp_path / "s.zarr")
    assert len(src) == 3 and src.units is None
    np.testing.assert_array_equal(src[2], stack[2])
    g = zarr.open_group(tmp_path / "o.zarr", mode="w")
    g.create_array("0", data=stack, chunks=(1, *SHAPE))
    g.attrs["multiscales"] = [{"version": "0.4", "axes": [
        {"name": "t", "type": "time", "unit": "second"},
        {"name": "y", "type": "space", "unit": "micrometer"},
        {"name": "x", "type": "space", "unit": "micrometer"}],
        "datasets": [{"path": "0", "coordinateTransformations": [
            {"type": "scale", "scale": [2.0, 0.65, 0.65]}]}]}]
    src = FrameSource(tmp_path / "o.zarr")
    assert (src.units.pixel_size, src.units.unit, src.units.frame_interval) == (0.65, "um", 2.0)
    np.testing.assert_array_equal(src[1], stack[1])


def test_zarr_pair_as_a_list_of_images(tmp_path, stack):
    for k in (0, 1):
        zarr.open_array(tmp_path / f"{k}.zarr", mode="w", shape=SHAPE, dtype=stack.dtype)[:] = \
            stack[k]
    pair = FrameSource([tmp_path / "0.zarr", tmp_path / "1.zarr"])
    assert len(pair) == 2
    np.testing.assert_array_equal(pair[1], stack[1])


def test_track_takes_units_from_the_stack(tmp_path, stack):
    from napari_aldic.engine import track

    seq = track(_imagej(tmp_path / "ij.tif", stack), subset=21, step=16, frames=[0, 1])
    assert seq[1].meta["units"]["pixel_size"] == 0.25
    assert seq[1].meta["units"]["frame_interval"] == 2.0
    assert seq[1].meta["units_source"]["pixel_size"] == "ImageJ metadata of ij.tif"
