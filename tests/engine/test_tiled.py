"""Images larger than memory (issue 13, section 2): lazy tile-by-tile reading
(tiled/strip TIFF, BigTIFF, zarr, OME-Zarr), pixel sizes from metadata, and Local
DIC block by block giving the untiled result."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
import zarr

from napari_aldic.engine import (
    DICParams,
    Reason,
    correlate,
    correlate_tiled,
    needs_tiling,
    synthetic as S,
)
from napari_aldic.engine.io import open_image, open_lazy, pixel_size_of
from napari_aldic.engine.workflow.tiled import coarse_guess

FIELD = S.Affine(G=((0.004, 0.001), (-0.002, 0.003)), center=(256.0, 256.0), t=(2.3, -1.6))


def _pair(n: int):
    return S.speckle_pair((n, n), FIELD, noise=1.0, n_quad=1, seed=5)


def _compare_with_untiled(ref, dfm, step: int, tile: int):
    """Tiled vs the same analysis untiled (same shared guess), and vs plain correlate."""
    tiled = correlate_tiled(ref, dfm, step=step, tile_size=tile, workers=2, search=10)
    assert tiled.meta["tiled"]["blocks"] >= 4
    guess = coarse_guess(ref, dfm, params=tiled.params, tile_size=tile)
    # the untiled run measures the speckle scale itself (no shared value)
    same = {"guess_of_this_pair": True}  # the guess is this pair's own coarse result
    whole = correlate(ref, dfm, params=tiled.params.replace(extra=same), guess=guess)
    assert np.array_equal(tiled.x, whole.x) and np.array_equal(tiled.y, whole.y)
    assert np.array_equal(tiled.reason, whole.reason)
    # every per-image choice is shared (search range, B-spline order, the
    # speckle scale of the Jacobian smoothing): blocks reproduce the whole
    # image's computation
    for name in ("u", "v", "dudx", "dudy", "dvdx", "dvdy", "zncc"):
        a, b = getattr(tiled, name), getattr(whole, name)
        assert np.nanmax(np.abs(a - b)) < 1e-6, name
    assert np.array_equal(tiled.iterations, whole.iterations)
    # plain correlate starts IC-GN elsewhere: the same nodes converge to the
    # same match within the IC-GN tolerance
    plain = correlate(ref, dfm, step=step, search=10, search_max=tiled.params.search_max)
    assert np.array_equal(tiled.valid, plain.valid)
    ok = tiled.valid
    assert ok.mean() > 0.9
    assert np.max(np.abs(tiled.u[ok] - plain.u[ok])) < 1e-3
    assert np.max(np.abs(tiled.v[ok] - plain.v[ok])) < 1e-3
    tu, tv = FIELD.displacement(tiled.x, tiled.y)
    assert np.max(np.hypot(tiled.u - tu, tiled.v - tv)[ok]) < 0.05


def test_tiled_equals_untiled_small():
    ref, dfm = _pair(512)
    _compare_with_untiled(ref, dfm, step=16, tile=160)


@pytest.mark.slow
def test_tiled_equals_untiled_2048():
    ref, dfm = _pair(2048)
    _compare_with_untiled(ref, dfm, step=32, tile=512)


def test_tiled_from_files_with_roi_and_memmap(tmp_path):
    ref, dfm = _pair(512)
    tifffile.imwrite(tmp_path / "r.tif", ref, tile=(128, 128), bigtiff=True)
    tifffile.imwrite(tmp_path / "d.tif", dfm, tile=(128, 128), bigtiff=True)
    roi = np.ones(ref.shape, bool)
    roi[200:330, 150:420] = False  # a hole across block borders
    res = correlate_tiled(tmp_path / "r.tif", tmp_path / "d.tif", roi=roi, step=16,
                          tile_size=192, search=10, out_dir=tmp_path / "nodes")
    assert (tmp_path / "nodes" / "u.npy").exists()
    guess = coarse_guess(ref, dfm, roi, params=res.params, tile_size=192)
    same = {"guess_of_this_pair": True}  # the guess is this pair's own coarse result
    whole = correlate(ref, dfm, roi=roi, params=res.params.replace(extra=same), guess=guess)
    assert np.array_equal(res.x, whole.x) and np.array_equal(res.y, whole.y)
    assert not np.any(roi[res.y.astype(int), res.x.astype(int)] == 0)
    ok = res.valid & whole.valid
    assert ok.sum() > 0.9 * whole.valid.sum()
    assert np.max(np.abs(res.u[ok] - whole.u[ok])) < 1e-6


def test_blank_region_is_flagged_not_fatal():
    ref, dfm = _pair(384)
    ref[:, :200] = 100  # no texture in the left part
    dfm[:, :200] = 100
    res = correlate_tiled(ref, dfm, step=16, tile_size=128, search=8)
    left = res.x < 120
    assert not res.valid[left].any()
    assert np.all(np.isin(res.reason[left], [Reason.NO_TEXTURE, Reason.NOT_CONVERGED,
                                             Reason.LOW_CORRELATION, Reason.POOR_MATCH,
                                             Reason.DIVERGED, Reason.UNCERTAIN]))
    assert res.valid[res.x > 240].mean() > 0.9


def test_tiled_refuses_what_needs_the_whole_image():
    ref, dfm = _pair(128)
    with pytest.raises(ValueError, match="refinement"):
        correlate_tiled(ref, dfm, method="aldic", refine="light")
    with pytest.raises(ValueError, match="seed"):
        correlate_tiled(ref, dfm, params=DICParams(init="seeds", seeds=[(60, 60)]))
    with pytest.raises(ValueError, match="same size"):
        correlate_tiled(ref, dfm[:100])
    assert needs_tiling((10_000, 10_000)) and not needs_tiling((4096, 4096))


# ---------------------------------------------------------------- lazy reading
def test_tiled_bigtiff_reads_only_the_tiles_of_a_window(tmp_path, monkeypatch):
    img = np.random.default_rng(0).integers(0, 255, (2048, 1536), np.uint8)
    path = tmp_path / "big.tif"
    tifffile.imwrite(path, img, tile=(256, 256), bigtiff=True)
    reads = []
    real = tifffile.FileCache.read

    def spy(self, fh, offset, bytecount, *a, **k):
        reads.append(bytecount)
        return real(self, fh, offset, bytecount, *a, **k)

    monkeypatch.setattr(tifffile.FileCache, "read", spy)
    with open_lazy(path) as lazy:
        assert lazy.shape == img.shape and lazy.chunks == (256, 256)
        win = lazy[200:500, 700:900]  # inside 2 x 2 of the 48 tiles
    assert np.array_equal(win, img[200:500, 700:900])
    assert len(reads) == 4 and sum(reads) == 4 * 256 * 256


def test_strip_tiff_reads_row_bands(tmp_path):
    img = np.random.default_rng(1).integers(0, 65535, (900, 700), np.uint16)
    for kw in ({"rowsperstrip": 16}, {}):  # strips, and one contiguous piece
        path = tmp_path / f"s{len(kw)}.tif"
        tifffile.imwrite(path, img, **kw)
        with open_lazy(path) as lazy:
            assert np.array_equal(lazy[10:400, 5:600], img[10:400, 5:600])
            assert lazy.bytes_read == 390 * 595 * 2


def test_zarr_reads_only_needed_chunks(tmp_path):
    img = np.random.default_rng(2).random((512, 512)).astype(np.float32)
    z = zarr.open_array(tmp_path / "img.zarr", mode="w", shape=img.shape, chunks=(128, 128),
                        dtype="f4", zarr_format=2)
    z[:] = img
    needed = {(r, c) for r in (1, 2) for c in (0, 1)}  # rows 130-300, cols 10-200
    for r in range(4):
        for c in range(4):
            if (r, c) not in needed:  # any read of these would fail to decode
                (tmp_path / "img.zarr" / f"{r}.{c}").write_bytes(b"not a chunk")
    lazy = open_lazy(tmp_path / "img.zarr")
    assert np.array_equal(lazy[130:300, 10:200], img[130:300, 10:200])
    with pytest.raises(ValueError, match="img.zarr"):
        lazy[0:10, 0:10]


def test_ome_zarr_level0_and_pixel_size(tmp_path):
    img = np.random.default_rng(3).integers(0, 255, (1, 1, 300, 400), np.uint8)
    root = zarr.open_group(tmp_path / "img.ome.zarr", mode="w", zarr_format=2)
    root.create_array("0", data=img, chunks=(1, 1, 128, 128))
    root.create_array("1", data=img[..., ::2, ::2], chunks=(1, 1, 128, 128))
    axes = [{"name": "c", "type": "channel"}, {"name": "z", "type": "space"},
            {"name": "y", "type": "space", "unit": "micrometer"},
            {"name": "x", "type": "space", "unit": "micrometer"}]
    root.attrs["multiscales"] = [{"version": "0.4", "axes": axes, "datasets": [
        {"path": "0", "coordinateTransformations": [{"type": "scale",
                                                      "scale": [1, 1, 0.25, 0.25]}]},
        {"path": "1", "coordinateTransformations": [{"type": "scale",
                                                      "scale": [1, 1, 0.5, 0.5]}]}]}]
    lazy = open_image(tmp_path / "img.ome.zarr")
    assert lazy.shape == (300, 400)
    assert np.array_equal(lazy[50:100, 60:90], img[0, 0, 50:100, 60:90])
    ps = lazy.pixel_size
    assert (ps.value, ps.unit, ps.source) == (0.25, "um", "OME-Zarr")


# ---------------------------------------------------------------- pixel size
def test_pixel_size_from_tiff_metadata(tmp_path):
    img = np.zeros((64, 64), np.uint8)
    tifffile.imwrite(tmp_path / "cm.tif", img, resolution=(2000.0, 2000.0),
                     resolutionunit="CENTIMETER")
    tifffile.imwrite(tmp_path / "ij.tif", img, imagej=True, resolution=(20.0, 20.0),
                     metadata={"unit": "micron"})
    tifffile.imwrite(tmp_path / "ome.tif", img, ome=True,
                     metadata={"PhysicalSizeX": 3.5, "PhysicalSizeXUnit": "nm"})
    tifffile.imwrite(tmp_path / "dpi.tif", img, resolution=(72.0, 72.0), resolutionunit="INCH")
    tifffile.imwrite(tmp_path / "none.tif", img)
    got = {name: pixel_size_of(tmp_path / f"{name}.tif") for name in
           ("cm", "ij", "ome", "dpi", "none")}
    assert (got["cm"].value, got["cm"].unit) == (5.0, "um")  # 1/2000 cm
    assert (got["ij"].value, got["ij"].unit, got["ij"].source) == (0.05, "um", "ImageJ")
    assert (got["ome"].value, got["ome"].unit, got["ome"].source) == (3.5, "nm", "OME-XML")
    assert got["dpi"] is None and got["none"] is None


# ---------------------------------------------------------------- bad input
def test_bad_files_are_named(tmp_path):
    bad = tmp_path / "broken.tif"
    bad.write_bytes(b"this is not a TIFF file at all")
    with pytest.raises(ValueError, match="broken.tif"):
        open_lazy(bad)
    with pytest.raises(FileNotFoundError, match="missing.tif"):
        open_lazy(tmp_path / "missing.tif")
    (tmp_path / "folder").mkdir()
    with pytest.raises(ValueError, match="folder"):
        open_image(tmp_path / "folder")
    (tmp_path / "odd.zarr").mkdir()
    (tmp_path / "odd.zarr" / "zarr.json").write_text(json.dumps({"zarr_format": 3,
                                                                 "node_type": "group"}))
    with pytest.raises(ValueError, match="odd.zarr"):
        open_lazy(tmp_path / "odd.zarr")
    stack = tmp_path / "stack.tif"
    tifffile.imwrite(stack, np.zeros((3, 32, 32), np.uint8))
    with pytest.raises(ValueError, match="stack.tif.*2-D"):
        open_lazy(stack)
    with pytest.raises(ValueError, match="broken.tif"):
        correlate_tiled(bad, bad)


def test_coarse_guess_skips_the_quality_maps():
    """The shared initial guess only starts the nodes: its blocks skip the
    speckle-quality stage (``extra={"quality": False}``), which would cost as
    much as their correlation."""
    ref, dfm = _pair(256)
    params = DICParams(search=10, search_max=40, interpolation="cubic")
    guess = coarse_guess(ref, dfm, params=params, tile_size=128)
    assert guess.valid.mean() > 0.9 and np.isnan(guess.sssig).all()
    full = correlate(ref, dfm, params=params)
    bare = correlate(ref, dfm, params=params.replace(extra={"quality": False}))
    assert "quality" in full.meta["timing"] and "quality" not in bare.meta["timing"]
    assert bare.sssig is None and np.array_equal(bare.u, full.u)
