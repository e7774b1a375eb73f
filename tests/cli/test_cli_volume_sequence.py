"""``napari-aldic run --volume --reference incremental`` on a 4-D TIFF gives the API's frames."""

from __future__ import annotations

import numpy as np
import tifffile

from napari_aldic.engine import load_result, track_volumes
from napari_aldic.engine.synthetic.volume import VolumeMotion, speckle_volume_pair


def test_cli_incremental_sequence_matches_the_api(run_cli, tmp_path):
    shape = (40, 40, 40)
    seq = np.stack([speckle_volume_pair(shape, VolumeMotion.make(shift=(0.7 * k, 0, -0.4 * k),
                                                                 angle_deg=1.5 * k,
                                                                 centre=(19.5,) * 3), seed=3)[1]
                    for k in range(3)])
    tifffile.imwrite(tmp_path / "seq.tif", seq)
    api = dict(track_volumes(seq, reference="incremental", subset=21, step=8))
    rc, out, err = run_cli(["run", tmp_path / "seq.tif", "--volume", "--reference",
                            "incremental", "-o", tmp_path / "run"])
    assert rc == 0, err
    for k in (1, 2):
        res = load_result(tmp_path / "run" / f"frame_{k:05d}.npz")
        np.testing.assert_allclose(res.u, api[k].u, atol=1e-9)
        np.testing.assert_array_equal(res.valid, api[k].valid)
    # rerun: frames already there are kept, not recomputed
    (tmp_path / "run" / "frame_00002.npz").unlink()
    mtime = (tmp_path / "run" / "frame_00001.npz").stat().st_mtime_ns
    rc, out, err = run_cli(["run", tmp_path / "seq.tif", "--volume", "--reference",
                            "incremental", "-o", tmp_path / "run"])
    assert rc == 0, err
    assert (tmp_path / "run" / "frame_00001.npz").stat().st_mtime_ns == mtime
    np.testing.assert_allclose(load_result(tmp_path / "run" / "frame_00002.npz").u, api[2].u,
                               atol=1e-9)


def test_cli_block_sequence_of_tiled_volumes_in_a_folder(run_cli, tmp_path):
    shape = (40, 40, 40)
    folder = tmp_path / "vols"
    folder.mkdir()
    seq = [speckle_volume_pair(shape, VolumeMotion.make(shift=(0.6 * k, -0.3 * k, 0.2 * k)),
                               seed=4)[1] for k in range(3)]
    for k, vol in enumerate(seq):  # natural order: vol_2 before vol_10
        tifffile.imwrite(folder / f"vol_{k}.tif", vol, tile=(16, 16))
    api = dict(track_volumes(seq, reference="accumulative", subset=21, step=8, block=16))
    rc, out, err = run_cli(["run", folder, "--volume", "--block", "16", "-o", tmp_path / "run"])
    assert rc == 0, err
    for k in (1, 2):
        res = load_result(tmp_path / "run" / f"frame_{k:05d}.npz")
        assert res.meta["blocked"]["blocks"] == 8
        np.testing.assert_array_equal(res.u, api[k].u)
        assert np.abs(res.u[res.valid] - 0.6 * k).max() < 0.01
