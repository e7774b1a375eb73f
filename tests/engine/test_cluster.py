"""Long sequences on a dask cluster: frames read by the workers, results in
the run folder's field store (fields.zarr), resume from it, flat memory."""

import gc
import io
import json
from contextlib import redirect_stderr, redirect_stdout

import numpy as np
import pytest
import tifffile

from napari_aldic.engine import DICResult, track
from napari_aldic.engine.io import load_run
from napari_aldic.engine.io.zarrstore import STORE_FIELDS, open_fields

FAST = {"subset": 21, "step": 12}


@pytest.fixture
def tif(export_stack, tmp_path):
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, export_stack, photometric="minisblack")
    return path


@pytest.fixture(scope="module")
def client():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as cl:
        yield cl


def _same(a, b, atol=1e-9):
    for k in range(1, len(a)):
        np.testing.assert_allclose(a[k].u, b[k].u, atol=atol)
        np.testing.assert_allclose(a[k].v, b[k].v, atol=atol)
        np.testing.assert_array_equal(a[k].valid, b[k].valid)


@pytest.mark.parametrize("reference", ["accumulative", "incremental"])
def test_cluster_run_from_a_path_equals_the_threaded_run(tif, tmp_path, client, reference):
    threaded = track(tif, scheduler="threads", workers=2, reference=reference, **FAST)
    out = tmp_path / "run"
    sent, scattered = [], []
    submit, scatter = client.submit, client.scatter

    def spy_submit(fn, *args, **kw):
        sent.append(args)
        return submit(fn, *args, **kw)

    def spy_scatter(data, **kw):
        scattered.append(data)
        return scatter(data, **kw)

    client.submit, client.scatter = spy_submit, spy_scatter
    try:
        dist = track(tif, scheduler=client, out_dir=out, reference=reference, **FAST)
    finally:
        del client.submit, client.scatter
    _same(dist, threaded)
    # tasks carry frame numbers and futures, never pixels; the frames were
    # read on the workers from the file (sent once, as a path)
    assert len(sent) == 3
    assert not any(isinstance(a, np.ndarray) for args in sent for a in args)
    frames = [d for d in scattered if isinstance(d, np.ndarray) and d.dtype != bool]
    assert len(frames) == (1 if reference == "accumulative" else 0)  # frame 0 once
    # one Numba thread per task by default (no oversubscribed workers)
    assert dist[1].params.n_threads == 1
    # the worker read the frames itself from the TIFF: named as frames of the file
    assert dist[3].meta["inputs"]["deformed"] == f"{tif}[3]"
    _same(load_run(out), threaded)


def test_cluster_run_of_an_array_equals_the_threaded_run(export_stack, client):
    threaded = track(export_stack, scheduler="threads", workers=2, **FAST)
    _same(track(export_stack, scheduler=client, **FAST), threaded)
    inc = track(export_stack, scheduler=client, reference="incremental", **FAST)
    _same(inc, track(export_stack, scheduler="threads", reference="incremental", **FAST))


def test_the_field_store_holds_every_frame(tif, tmp_path):
    out = tmp_path / "run"
    seq = track(tif, out_dir=out, **FAST)
    g = open_fields(out)
    manifest = json.loads((out / "sequence.json").read_text())
    assert g.attrs["run_id"] == manifest["run_id"] and g.attrs["frames"] == [0, 1, 2, 3]
    ny, nx = seq[0].grid_shape
    assert g["u"].shape == (4, ny, nx) and g["u"].chunks == (1, ny, nx)
    np.testing.assert_array_equal(g["done"][:], True)
    np.testing.assert_array_equal(g["frame"][:], [0, 1, 2, 3])
    for k in range(1, 4):
        for name in STORE_FIELDS:
            np.testing.assert_array_equal(g[name][k], seq[k].to_grid(name, invalid=None))
        np.testing.assert_array_equal(g["valid"][k], seq[k].to_grid("valid", invalid=None) > 0)
        assert g["n_valid"][k] == seq[k].n_valid > 0
    # displacement really stored: frame 3 moves (export field), frame 0 does not
    assert np.nanmax(np.abs(g["u"][3])) > 0.5 and np.nanmax(np.abs(g["u"][0])) == 0


def test_resume_from_the_store_computes_only_the_missing_frames(tif, tmp_path, client):
    out = tmp_path / "run"
    first = track(tif, out_dir=out, scheduler=client, **FAST)
    (out / "frame_00003.npz").unlink()  # killed before frame 3 was written
    before = (out / "frame_00001.npz").stat().st_mtime_ns
    seen = []
    again = track(tif, out_dir=out, scheduler=client,
                  progress=lambda k, f, msg: seen.append(msg), **FAST)
    assert sum("loaded from" in m for m in seen) == 2
    assert sum("done" in m for m in seen) == 1
    assert (out / "frame_00001.npz").stat().st_mtime_ns == before  # not rewritten
    _same(again, first)
    g = open_fields(out)
    np.testing.assert_array_equal(g["u"][3], first[3].to_grid("u", invalid=None))


def test_a_result_file_missing_from_the_store_is_checked_and_added(tif, tmp_path):
    import zarr

    out = tmp_path / "run"
    first = track(tif, out_dir=out, **FAST)
    g = zarr.open_group(str(out / "fields.zarr"), mode="a")
    g["done"][2] = False  # killed between the result file and the store's record
    g["u"][2] = np.full(g["u"].shape[1:], 99.0)
    seen = []
    track(tif, out_dir=out, progress=lambda k, f, msg: seen.append(msg), **FAST)
    assert not any("done" in m for m in seen)  # nothing recomputed
    g = open_fields(out)
    assert g["done"][2]
    np.testing.assert_array_equal(g["u"][2], first[2].to_grid("u", invalid=None))


def _live_results() -> int:
    gc.collect()
    # type(), not isinstance(): isinstance() of a dead weakref.proxy (left in
    # memory by an earlier test) raises ReferenceError
    return sum(issubclass(type(o), DICResult) for o in gc.get_objects())


def test_client_keeps_only_what_composition_needs(export_stack, tmp_path):
    stack = np.concatenate([export_stack, export_stack[::-1]])  # 8 frames
    base = _live_results()
    seq = track(stack, out_dir=tmp_path / "run", reference="incremental", **FAST)
    held = _live_results() - base
    assert held <= 2, held  # frame 0 and at most the last reference
    assert seq.complete and seq[7].n_valid > 0  # frames read back when used
    whole = track(stack, reference="incremental", **FAST)  # no folder: all in memory
    assert _live_results() - base >= held + 8
    _same(seq, whole)


def test_cli_scheduler_option(tif, tmp_path):
    from napari_aldic.cli import main

    out = tmp_path / "run"
    buf, err = io.StringIO(), io.StringIO()
    with redirect_stdout(buf), redirect_stderr(err):
        rc = main(["run", str(tif), "-o", str(out), "--subset", "21", "--step", "12",
                   "--scheduler", "threads", "--workers", "2"])
    assert rc == 0, err.getvalue()
    assert "3 frames in" in buf.getvalue() and open_fields(out)["done"][:].all()
    with redirect_stdout(io.StringIO()), redirect_stderr(err := io.StringIO()):
        rc = main(["run", str(tif), "-o", str(tmp_path / "b"), "--scheduler", "cluster"])
    assert rc == 2 and "'cluster' is not 'threads', 'processes' or a dask" in err.getvalue()


@pytest.mark.slow  # starts two worker processes (about 10 s)
def test_processes_scheduler_equals_threads(tif, tmp_path):
    pytest.importorskip("distributed")
    threaded = track(tif, scheduler="threads", workers=2, **FAST)
    _same(track(tif, scheduler="processes", workers=2, out_dir=tmp_path / "run", **FAST),
          threaded)
