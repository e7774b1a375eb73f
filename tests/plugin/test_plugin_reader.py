"""The npe2 reader and writers, and the layer/ROI helpers (no viewer needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile

from napari_aldic._analysis import run_analysis
from napari_aldic._layers import Geometry, analysis_layers
from napari_aldic._reader import get_reader, read_results
from napari_aldic._roi import shape_mask
from napari_aldic._writer import write_export, write_results
from napari_aldic.engine import DICParams, correlate
from napari_aldic.engine.io import read_csv
from napari_aldic.engine.viz import to_deformed


def _by_field(layers) -> dict:
    """Layer-data tuples by the field they show (names carry the unit)."""
    return {kw["metadata"]["napari_aldic"]["field"]: (d, kw, k) for d, kw, k in layers}


def test_tiff_stack_opens_as_one_lazy_16bit_layer(tmp_path):
    import dask.array as da

    rng = np.random.default_rng(0)
    stack = rng.integers(0, 65535, (4, 40, 56), dtype=np.uint16)
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, stack, photometric="minisblack")
    reader = get_reader(str(path))
    assert callable(reader)
    [(data, kwargs, kind)] = reader(str(path))
    assert kind == "image"
    assert isinstance(data, da.Array)  # lazy: frames are read when needed
    assert data.shape == (4, 40, 56) and data.dtype == np.uint16
    np.testing.assert_array_equal(np.asarray(data[2]), stack[2])
    np.testing.assert_array_equal(data.compute(), stack)
    assert kwargs["axis_labels"] == ("t", "y", "x")
    assert kwargs["contrast_limits"][1] > kwargs["contrast_limits"][0]


def test_single_images_are_left_to_other_readers(tmp_path):
    path = tmp_path / "one.tif"
    tifffile.imwrite(path, np.zeros((30, 30), np.uint16))
    assert get_reader(str(path)) is None
    assert get_reader(str(tmp_path / "missing.tif")) is None
    assert get_reader(str(tmp_path)) is None  # a folder with one image is no sequence
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    assert get_reader(str(tmp_path / "other.npz")) is None  # not our result format


@pytest.mark.parametrize("ext", [".png", ".bmp", ".tif"])
def test_image_folder_natural_sort(tmp_path, ext):
    from skimage import io

    dtype = np.uint8 if ext == ".bmp" else np.uint16
    for k in (1, 2, 10, 11):  # natural order: 1, 2, 10, 11 (not 1, 10, 11, 2)
        img = np.full((24, 32), 1000 * k if dtype == np.uint16 else 10 * k, dtype)
        if ext == ".tif":
            tifffile.imwrite(tmp_path / f"img_{k}{ext}", img)
        else:
            io.imsave(tmp_path / f"img_{k}{ext}", img, check_contrast=False)
    (tmp_path / "notes.txt").write_text("not an image")
    reader = get_reader(str(tmp_path))
    assert callable(reader)
    [(data, kwargs, _)] = reader(str(tmp_path))
    assert data.shape == (4, 24, 32) and data.dtype == dtype  # 16-bit kept
    firsts = [int(np.asarray(data[k])[0, 0]) for k in range(4)]
    scale = 1000 if dtype == np.uint16 else 10
    assert firsts == [scale * k for k in (1, 2, 10, 11)]
    assert kwargs["metadata"]["frames"][:3] == [f"img_1{ext}", f"img_2{ext}", f"img_10{ext}"]
    # the same files chosen together open as one stack too
    files = [str(tmp_path / f"img_{k}{ext}") for k in (10, 1, 11, 2)]
    [(data2, _, _)] = get_reader(files)(files)
    np.testing.assert_array_equal(np.asarray(data2), np.asarray(data))


def test_result_file_reopens_as_result_layers(tmp_path, speckle_stack):
    stack = speckle_stack()
    res = correlate(stack[0], stack[2], subset=21, step=8)
    path = res.save(tmp_path / "pair.npz")
    reader = get_reader(str(path))
    assert callable(reader)
    layers = _by_field(reader(str(path)))
    assert {"u", "v", "|u|", "exx", "von Mises", "displacement", "unreliable nodes"} <= \
        set(layers)
    u, kw, kind = layers["u"]
    assert kw["name"] == "DIC u [px]"  # the unit is in the name (and the status bar)
    assert kind == "image" and u.ndim == 2
    np.testing.assert_allclose(u, res.to_grid("u"), equal_nan=True, rtol=1e-6)
    # one lattice pixel per node: scale = step, origin at the first node
    assert kw["scale"] == (8.0, 8.0)
    assert kw["translate"] == (float(res.grid_ys[0]), float(res.grid_xs[0]))
    lo, hi = kw["contrast_limits"]  # robust limits from the data
    assert np.nanmin(u) <= lo < hi <= np.nanmax(u)
    assert np.mean((u >= lo) & (u <= hi)) > 0.95 * np.isfinite(u).mean()
    vec, vkw, vkind = layers["displacement"]
    assert vkind == "vectors" and len(vkw["features"]["u"]) == res.n_valid


def test_sequence_writer_and_reader_round_trip(tmp_path, speckle_stack):
    stack = speckle_stack()
    analysis = run_analysis(stack, None, DICParams(subset=21, step=12))
    geo = Geometry((1.0, 1.0, 1.0), (0.0, 0.0, 0.0))
    layers = _by_field(analysis_layers(analysis, geo))
    data, kw, _ = layers["u"]
    assert data.shape[0] == 3
    written = write_results(str(tmp_path / "run.npz"), data, kw)
    assert len(written) == 3 and (tmp_path / "run" / "frame_00002.npz").exists()
    back = {f: d for f, (d, _, _) in _by_field(get_reader(str(tmp_path / "run"))(
        str(tmp_path / "run"))).items()}
    np.testing.assert_allclose(back["u"], data, equal_nan=True)
    np.testing.assert_allclose(back["exx"], layers["exx"][0], equal_nan=True, atol=1e-9)
    # the engine's exports, in the physical units of the layer
    kw_um = {**kw, "metadata": {**kw["metadata"], "napari_aldic": {
        **kw["metadata"]["napari_aldic"], "pixel_size": 0.5, "length_unit": "um",
        "frame_interval": 2.0, "time_unit": "s"}}}
    [csv_path] = write_export(str(tmp_path / "nodes.csv"), data, kw_um)
    table = read_csv(csv_path)
    assert table["units"]["u"] == "um" and table["settings"].pixel_size == 0.5
    last = table["columns"]["frame"] == 2
    np.testing.assert_allclose(table["columns"]["u"][last],
                               0.5 * analysis.results[2].u, rtol=1e-6)
    [mat_path] = write_export(str(tmp_path / "nodes.mat"), data, kw_um)
    assert Path(mat_path).stat().st_size > 1000
    # saved units come back with the layers: scale, axis units and displayed values
    write_results(str(tmp_path / "run_um.npz"), data, kw_um)
    back = _by_field(read_results(str(tmp_path / "run_um")))
    u_um, ukw, _ = back["u"]
    assert ukw["name"] == "DIC u [um]"
    np.testing.assert_allclose(u_um, 0.5 * data, equal_nan=True, rtol=1e-6)
    assert ukw["scale"] == (2.0, 6.0, 6.0) and ukw["units"] == ("s", "um", "um")
    with pytest.raises(ValueError, match="no napari-aldic results"):
        write_results(str(tmp_path / "x.npz"), data, {"metadata": {}})


def test_shape_masks():
    shape = (60, 80)
    rect = shape_mask("rectangle", np.array([[10, 20], [10, 59], [39, 59], [39, 20]]), shape)
    assert rect.sum() == 30 * 40 and rect[10, 20] and not rect[9, 20]
    # napari stores an ellipse as the 4 corners of its bounding box
    ell = shape_mask("ellipse", np.array([[20, 30], [20, 50], [40, 50], [40, 30]]), shape)
    rr, cc = np.mgrid[0:60, 0:80]
    truth = ((rr - 30) / 10.0) ** 2 + ((cc - 40) / 10.0) ** 2 <= 1
    assert (ell == truth).all()
    cut = shape_mask("path", np.array([[30, 0], [30, 40]]), shape, width=3)
    assert cut[29:32, :41].all() and not cut[27, 10] and not cut[30, 45]


def test_deformed_configuration_moves_the_field():
    u = np.full((10, 12), 2.0 * 4)  # 2 lattice steps of 4 px to the right
    v = np.zeros((10, 12))
    g = np.tile(np.arange(12, dtype=float), (10, 1))  # value = column index
    [moved] = to_deformed([g], u, v, step=4.0)
    # the material of column c now sits at column c + 2
    np.testing.assert_allclose(moved[:, 2:], g[:, :-2])
    assert np.isnan(moved[:, :2]).all()  # no material reaches there
