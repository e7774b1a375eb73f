"""``napari-aldic run REF DEF -o OUT.npz`` on a tiled TIFF pair, block by block
(issue 13, section 2): the tiled path end to end, units from the image metadata,
and clear errors."""

from __future__ import annotations

import numpy as np
import tifffile

from napari_aldic.engine import load_result, synthetic as S

FIELD = S.Affine(G=((0.003, 0.0), (0.001, -0.002)), center=(200.0, 200.0), t=(1.4, -0.8))


def _write_pair(tmp_path):
    ref, dfm = S.speckle_pair((400, 400), FIELD, noise=1.0, n_quad=1, seed=2)
    tifffile.imwrite(tmp_path / "ref.tif", ref, tile=(128, 128), bigtiff=True,
                     imagej=False, resolution=(1e4, 1e4), resolutionunit="CENTIMETER")
    tifffile.imwrite(tmp_path / "def.tif", dfm, tile=(128, 128), bigtiff=True)
    return tmp_path / "ref.tif", tmp_path / "def.tif"


def test_run_tiled_pair_end_to_end(run_cli, tmp_path):
    ref, dfm = _write_pair(tmp_path)
    out = tmp_path / "out.npz"
    rc, stdout, err = run_cli(["run", ref, dfm, "--step", 16, "--tile-size", 128,
                               "--tile-workers", 2, "-o", out])
    assert rc == 0, err
    assert "blocks of 128 px" in stdout
    assert "pixel size 1 um" in stdout  # 1e4 pixels per cm
    res = load_result(out)
    assert res.meta["tiled"]["blocks"] >= 4
    assert res.meta["units"]["pixel_size"] == 1.0 and res.meta["units"]["unit"] == "um"
    assert res.image_shape == (400, 400)
    assert res.valid.mean() > 0.85
    u, v = FIELD.displacement(res.x, res.y)
    assert np.max(np.hypot(res.u - u, res.v - v)[res.valid]) < 0.05


def test_run_tiled_units_overridden(run_cli, tmp_path):
    ref, dfm = _write_pair(tmp_path)
    out = tmp_path / "o.npz"
    rc, stdout, err = run_cli(["run", ref, dfm, "--step", 24, "--tile-size", 200,
                               "--pixel-size", 2.5, "--unit", "nm", "-o", out])
    assert rc == 0, err
    assert "pixel size 1 um" not in stdout
    units = load_result(out).meta["units"]
    assert (units["pixel_size"], units["unit"]) == (2.5, "nm")


def test_run_tiled_bad_inputs(run_cli, tmp_path):
    ref, _ = _write_pair(tmp_path)
    bad = tmp_path / "broken.tif"
    bad.write_bytes(b"not a tiff")
    rc, _, err = run_cli(["run", ref, bad, "--tile-size", 128, "-o", tmp_path / "x.npz"])
    assert rc == 2 and "broken.tif" in err and "Traceback" not in err
    rc, _, err = run_cli(["run", ref, tmp_path / "missing.tif", "--tile-size", 128,
                          "-o", tmp_path / "x.npz"])
    assert rc == 2 and "missing.tif" in err
    rc, _, err = run_cli(["run", ref, ref, "--tile-size", -5, "-o", tmp_path / "x.npz"])
    assert rc == 2 and "--tile-size" in err
    rc, _, err = run_cli(["run", ref, ref, "--tile-size", 128, "--roi", tmp_path / "no.tif",
                          "-o", tmp_path / "x.npz"])
    assert rc == 2 and "no.tif" in err and "Traceback" not in err
    np.save(tmp_path / "small.npy", np.ones((100, 100), bool))
    rc, _, err = run_cli(["run", ref, ref, "--tile-size", 128, "--roi", tmp_path / "small.npy",
                          "-o", tmp_path / "x.npz"])
    assert rc == 2 and "ROI mask shape (100, 100)" in err


def test_run_tiled_aldic_with_lazy_roi(run_cli, tmp_path, monkeypatch):
    """AL-DIC of a pair read block by block, the ROI a tiled TIFF mask that is
    sliced block by block as well (never read whole)."""
    from napari_aldic.cli import masks

    def whole(path):
        raise AssertionError(f"{path} read whole")

    monkeypatch.setattr(masks, "read_image", whole)
    ref, dfm = _write_pair(tmp_path)
    mask = np.full((400, 400), 255, np.uint8)
    mask[150:260, 120:300] = 0  # a hole across block borders
    tifffile.imwrite(tmp_path / "roi.tif", mask, tile=(128, 128))
    out = tmp_path / "al.npz"
    rc, stdout, err = run_cli(["run", ref, dfm, "--step", 16, "--tile-size", 128,
                               "--method", "aldic", "--roi", tmp_path / "roi.tif", "-o", out])
    assert rc == 0, err
    res = load_result(out)
    assert res.params.method == "aldic" and res.meta["admm_history"]
    assert res.u_local is not None and res.elements is not None
    inside_hole = (res.x >= 120) & (res.x < 300) & (res.y >= 150) & (res.y < 260)
    assert not inside_hole.any()  # nodes only where the mask is nonzero
    assert res.valid.mean() > 0.8
    u, v = FIELD.displacement(res.x, res.y)
    assert np.max(np.hypot(res.u - u, res.v - v)[res.valid]) < 0.05
