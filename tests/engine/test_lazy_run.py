"""Run folders read frame by frame: load_run's frames load when used, and an
export of a run folder never holds all its frames at once."""

import contextlib
import io
import shutil
import weakref

import numpy as np
import pytest

from napari_aldic.cli import main as cli_main
from napari_aldic.engine import export_result, load_run, synthetic as S, track
from napari_aldic.engine.core import results as results_module
from napari_aldic.engine.core.results import LazyFrames, SequenceResult
from napari_aldic.engine.io import read_csv, runs as runs_module

N_FRAMES = 12
SHAPE = (96, 96)
UNITS = {"pixel_size": 0.5, "unit": "um", "frame_interval": 0.1}


def _field(k):
    return S.Affine.strain_rotation(exx=0.004 * k, eyy=-0.001 * k, center=(48.0, 48.0),
                                    t=(0.15 * k, -0.1 * k))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """(in-memory SequenceResult, its run folder) of a small 12-frame stack."""
    pat = S.make_pattern(SHAPE, seed=7, margin=32)
    stack = np.stack([S.render(pat, SHAPE, None if k == 0 else _field(k), n_quad=2,
                               seed=30 + k) for k in range(N_FRAMES)])
    folder = tmp_path_factory.mktemp("lazy_run")
    seq = track(stack, subset=21, step=12, out_dir=folder)
    # track with a run folder reads its frames back when used too: held here
    # in memory, before any test counts the reads
    held = SequenceResult(list(seq.frames), seq.params, seq.reference, seq.meta)
    assert isinstance(seq.frames, LazyFrames) and all(held.frames)
    return held, folder


@pytest.fixture
def loads(monkeypatch):
    """Every result read from a file: a list of (path, weak reference)."""
    seen = []
    real = results_module.load_result

    def counting(path):
        res = real(path)
        seen.append((str(path), weakref.ref(res)))
        return res

    for module in (results_module, runs_module):  # every reader of result files
        monkeypatch.setattr(module, "load_result", counting)
    return seen


def _watch(monkeypatch, loads) -> list[int]:
    """The number of results read and still alive, each time one more is read."""
    alive = []
    counting = results_module.load_result

    def watching(path):
        alive.append(sum(ref() is not None for _, ref in loads))
        return counting(path)

    for module in (results_module, runs_module):
        monkeypatch.setattr(module, "load_result", watching)
    return alive


def _copy(folder, tmp_path):
    dst = tmp_path / "run"
    shutil.copytree(folder, dst)
    return dst


def _same(a, b):
    for k in ("x", "y", "u", "v", "dudx", "dvdy", "valid", "zncc", "reason"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))


def test_frames_load_only_when_used(run, loads):
    eager, folder = run
    seq = load_run(folder)
    assert len(seq) == N_FRAMES and len(seq.frames) == N_FRAMES
    assert seq.complete and loads == []  # neither load_run nor complete read a frame
    _same(seq[3], eager[3])
    assert len(loads) == 1
    _same(seq.frames[3], eager[3])  # the frame just read is kept
    assert len(loads) == 1
    _same(seq[-1], eager[N_FRAMES - 1])
    _same(seq.frames[-2], eager[N_FRAMES - 2])
    assert [p.rsplit("_", 1)[-1] for p, _ in loads[1:]] == ["00011.npz", "00010.npz"]
    part = seq.frames[2:8:2]
    assert isinstance(part, list) and len(part) == 3
    for res, k in zip(part, (2, 4, 6)):
        _same(res, eager[k])
    with pytest.raises(IndexError):
        seq[N_FRAMES]
    with pytest.raises(IndexError):
        seq[-N_FRAMES - 1]
    assert [np.asarray(r.u).size for r in list(seq.frames)] == [len(r) for r in eager.frames]


def test_iterating_keeps_only_the_last_frames(run, loads):
    _, folder = run
    seq = load_run(folder)
    alive = []
    for k, res in enumerate(seq.frames):
        assert res.meta.get("frame", 0) == k
        alive.append(sum(ref() is not None for _, ref in loads))
        del res
    assert len(loads) == N_FRAMES and max(alive) <= 3


def test_a_missing_frame_is_none_and_nothing_is_read(run, loads, tmp_path):
    _, folder = run
    dst = _copy(folder, tmp_path)
    (dst / "frame_00005.npz").unlink()
    seq = load_run(dst)
    assert not seq.complete and loads == []
    assert seq.frames.present == tuple(k != 5 for k in range(N_FRAMES))
    assert seq[5] is None and seq.frames[-(N_FRAMES - 5)] is None and loads == []
    assert [r is None for r in seq.frames] == [k == 5 for k in range(N_FRAMES)]


def test_a_folder_of_result_files_is_ordered_by_stored_frame_and_lazy(run, loads, tmp_path):
    eager, _ = run
    folder = tmp_path / "files"
    folder.mkdir()
    # file names sort differently from the frame numbers stored in the results
    for k, name in ((3, "b_1.npz"), (1, "c_7.npz"), (2, "a_9.npz")):
        eager[k].save(folder / name)
    seq = load_run(folder)
    assert loads == [] and seq.meta["frames"] == [0, 1, 2, 3] and not seq.complete
    assert seq[0] is None
    for k in (1, 2, 3):
        _same(seq[k], eager[k])
    assert seq.params == eager[1].params
    (folder / "a_9.npz").write_bytes(b"")
    with pytest.raises(ValueError, match="the file is empty"):
        load_run(folder)


def test_exports_read_one_frame_at_a_time_and_match_the_eager_export(run, loads, tmp_path,
                                                                     monkeypatch):
    eager, folder = run
    eager_csv = export_result(eager, tmp_path / "eager.csv", units=UNITS)
    assert loads == []
    peak = _watch(monkeypatch, loads)
    lazy_csv = export_result(folder, tmp_path / "lazy.csv", units=UNITS)
    assert max(peak) <= 4 and len(peak) >= N_FRAMES  # a bound, not the number of frames
    a, b = read_csv(eager_csv)["columns"], read_csv(lazy_csv)["columns"]
    assert list(a) == list(b) and "exx_rate" in a and "vx" in a
    for name in a:  # strain, velocities and rates (previous frame) are the same
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def test_cli_export_of_a_run_folder_reads_one_frame_at_a_time(run, loads, tmp_path,
                                                               monkeypatch):
    _, folder = run
    dst = _copy(folder, tmp_path)
    alive = _watch(monkeypatch, loads)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli_main(["export", str(dst), "--to", "csv,vtu", "--frame-interval", "0.1"])
    assert rc == 0, err.getvalue()
    assert max(alive) <= 4 and len(alive) >= N_FRAMES
    cols = read_csv(dst / "export.csv")["columns"]
    assert sorted(set(cols["frame"])) == list(range(N_FRAMES))


def test_probes_of_a_run_folder_read_each_frame_once(run, loads, monkeypatch):
    """measure_probes goes frame by frame (every probe at once): a run folder
    is read once, a few frames alive at a time, with the in-memory values."""
    from napari_aldic.engine.probes import (
        AreaProbe,
        LineProbe,
        PointProbe,
        ProbeSet,
        measure_probes,
    )

    eager, folder = run
    probes = ProbeSet(lines=[LineProbe(30.0, 48.0, 66.0, 48.0)], points=[PointProbe(48.0, 40.0)],
                      areas=[AreaProbe("rectangle", (36.0, 36.0, 60.0, 60.0))])
    want = measure_probes(eager, probes)
    assert loads == []
    alive = _watch(monkeypatch, loads)
    got = measure_probes(folder, probes)
    paths = [path for path, _ in loads]
    assert len(paths) == N_FRAMES and len(set(paths)) == N_FRAMES  # each frame read once
    assert max(alive) <= 4
    assert list(got.columns) == list(want.columns)
    for name, col in want.columns.items():
        np.testing.assert_array_equal(got.columns[name].values, col.values, err_msg=name)
    # the line gauge follows the imposed strain (exx = 0.004 k)
    strain = got.columns["line1_strain"].values
    assert np.allclose(strain[1:], 0.004 * np.arange(1, N_FRAMES), atol=2e-3)


def test_a_list_of_result_files_is_read_when_used(run, loads, tmp_path, monkeypatch):
    """Result files given as a list (``napari-aldic export a.npz b.npz ...``)
    are ordered by the frame number in their headers and read one at a time."""
    eager, folder = run
    files = sorted(folder.glob("frame_*.npz"), reverse=True)  # any order: headers decide
    alive = _watch(monkeypatch, loads)
    lazy_csv = export_result([str(p) for p in files], tmp_path / "list.csv", units=UNITS)
    assert len(alive) >= N_FRAMES and max(alive) <= 4
    eager_csv = export_result(eager, tmp_path / "eager.csv", units=UNITS)
    a, b = read_csv(eager_csv)["columns"], read_csv(lazy_csv)["columns"]
    assert list(a) == list(b)
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
