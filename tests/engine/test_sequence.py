"""Sequences: track() in frame-0 coordinates, lazy inputs, resume."""

import numpy as np
import pytest
import tifffile

from napari_aldic.engine import compute_strain, open_stack, synthetic as S, track

N_FRAMES = 10
SHAPE = (192, 192)
C = (96.0, 96.0)


def _field(k):
    e = 0.05 * k / (N_FRAMES - 1)  # 0 -> 5 % uniform stretch along x
    return S.Affine.strain_rotation(exx=e, eyy=-0.3 * e, center=C, t=(0.2 * k, 0.1 * k))


@pytest.fixture(scope="module")
def stack():
    pat = S.make_pattern(SHAPE, seed=40, margin=64)
    frames = [S.render(pat, SHAPE, None if k == 0 else _field(k), n_quad=3, seed=100 + k)
              for k in range(N_FRAMES)]
    return np.stack(frames)


def _last_error(seq):
    res = seq[N_FRAMES - 1]
    ut, vt = _field(N_FRAMES - 1).displacement(res.x, res.y)
    v = res.valid
    return res, v, np.abs(res.u[v] - ut[v]).max(), np.abs(res.v[v] - vt[v]).max()


@pytest.mark.parametrize("reference", ["accumulative", "incremental"])
def test_growing_strain_sequence(stack, reference):
    seq = track(stack, subset=31, step=8, reference=reference)
    assert len(seq) == N_FRAMES and seq.complete
    assert np.all(seq[0].u == 0)
    res, v, eu, ev = _last_error(seq)
    assert v.mean() > 0.6
    assert eu < 0.02 and ev < 0.02
    # all frames share the frame-0 nodes (Lagrangian)
    np.testing.assert_array_equal(res.x, seq[0].x)
    st = compute_strain(res, window=5, measure="green_lagrange")
    G = np.asarray(_field(N_FRAMES - 1).G)
    exx_true = G[0, 0] + 0.5 * (G[0, 0] ** 2 + G[1, 0] ** 2)
    inner = st.valid & (np.hypot(res.x - C[0], res.y - C[1]) < 50)
    assert inner.sum() > 20
    assert np.abs(st.exx[inner] - exx_true).max() < 2e-4


def test_lazy_tiff_and_folder_inputs(stack, tmp_path):
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, stack[:4], photometric="minisblack")
    src = open_stack(path)
    assert len(src) == 4 and src.shape[1:] == SHAPE
    np.testing.assert_array_equal(src[2], stack[2])
    folder = tmp_path / "imgs"
    folder.mkdir()
    for k in (0, 1, 2, 10):  # natural sort: img_2 before img_10
        tifffile.imwrite(folder / f"img_{k}.tif", stack[min(k, 3)])
    src = open_stack(folder)
    assert [p.name for p in src._files] == ["img_0.tif", "img_1.tif", "img_2.tif", "img_10.tif"]
    seq = track(path, step=12)
    ref = track(stack[:4], step=12)
    np.testing.assert_allclose(seq[3].u, ref[3].u)


def test_cancel_keeps_finished_frames_and_resume(stack, tmp_path):
    out = tmp_path / "run"
    done = []

    def cancel():
        return len(done) >= 3

    def progress(k, frac, msg):
        if "done" in msg:
            done.append(k)

    seq = track(stack[:6], step=12, out_dir=out, cancel=cancel, progress=progress)
    assert seq.meta["cancelled"] and not seq.complete
    files = sorted(p.name for p in out.glob("frame_*.npz"))
    assert files == ["frame_00000.npz", "frame_00001.npz", "frame_00002.npz",
                     "frame_00003.npz"]
    loaded = []
    seq2 = track(stack[:6], step=12, out_dir=out,
                 progress=lambda k, f, m: loaded.append(k) if "loaded" in m else None)
    assert seq2.complete and loaded == [1, 2, 3]
    np.testing.assert_allclose(seq2[2].u, seq[2].u)
    with pytest.raises(ValueError, match="different analysis"):
        track(stack[:6], step=16, out_dir=out)


def test_bad_sequence_inputs(tmp_path):
    with pytest.raises(ValueError, match="3-D"):
        track(np.zeros((10, 10)))
    with pytest.raises(FileNotFoundError, match="no image stack"):
        track(tmp_path / "missing.tif")
    with pytest.raises(ValueError, match="reference='backward'"):
        track(np.zeros((2, 50, 50)), reference="backward")


def test_threads_and_local_cluster_agree(stack):
    from distributed import Client, LocalCluster

    sub = stack[:4]
    threaded = track(sub, step=12, scheduler="threads", workers=2)
    seq = track(sub, step=12)  # sequential, previous frame as the guess
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        dist = track(sub, step=12, scheduler=client)
    for k in range(1, 4):
        np.testing.assert_allclose(dist[k].u, threaded[k].u, atol=1e-9)
        np.testing.assert_allclose(dist[k].v, threaded[k].v, atol=1e-9)
        v = seq[k].valid & threaded[k].valid
        np.testing.assert_allclose(seq[k].u[v], threaded[k].u[v], atol=2e-3)


def test_incremental_in_parallel_matches_sequential(stack):
    par = track(stack[:5], step=12, reference="incremental", scheduler="threads")
    seq = track(stack[:5], step=12, reference="incremental")
    v = par[4].valid & seq[4].valid
    assert v.mean() > 0.6
    np.testing.assert_allclose(par[4].u[v], seq[4].u[v], atol=2e-3)


def test_cancel_inside_a_frame_is_prompt(stack):
    from napari_aldic.engine import Cancelled, correlate

    calls = []

    def cancel():
        calls.append(1)
        return len(calls) > 3  # stop a few stages into the analysis

    with pytest.raises(Cancelled):
        correlate(stack[0], stack[1], method="aldic", cancel=cancel)
    assert len(calls) == 4  # it stopped at the first check that said so

    done = []
    state = {"frame": 0}

    def cancel_in_frame_3():
        return state["frame"] == 3 and len(done) == 2

    def progress(k, frac, msg):
        state["frame"] = k
        if "done" in msg:
            done.append(k)

    seq = track(stack[:6], step=12, cancel=cancel_in_frame_3, progress=progress)
    assert seq.meta["cancelled"]
    assert seq[1] is not None and seq[2] is not None and seq[3] is None


def test_results_name_their_input_frames(stack, tmp_path):
    folder = tmp_path / "imgs"
    folder.mkdir()
    for k in range(3):
        tifffile.imwrite(folder / f"img_{k}.tif", stack[k])
    seq = track(folder, step=16, reference="incremental")
    assert seq[2].meta["inputs"]["reference"].endswith("img_1.tif")
    assert seq[2].meta["inputs"]["deformed"].endswith("img_2.tif")
