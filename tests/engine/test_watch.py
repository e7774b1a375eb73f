"""Live DIC (issue 26): frame files judged complete, the watch against offline ``track``,
live probes with a growing load file."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from napari_aldic.engine import LiveProbes, load_run, track, watch
from napari_aldic.engine.probes import LineProbe, ProbeSet
from napari_aldic.engine.synthetic.camera import _tiff_bytes, render_frames, write_frame
from napari_aldic.engine.workflow.watch_files import FrameFiles

SHAPE = (112, 112)
N = 5


@pytest.fixture(scope="module")
def frames():
    return render_frames(N, SHAPE, rate=0.004, drift=0.4)


def _poll(files: FrameFiles, seconds: float):
    """next_frame() for ``seconds`` (every 20 ms): the first frame found, or None."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        got = files.next_frame()
        if got is not None:
            return got
        time.sleep(0.02)
    return None


def test_half_written_and_empty_files_are_never_read(tmp_path, frames):
    files = FrameFiles(tmp_path, settle=0.1, stall=0.2)
    data = _tiff_bytes(frames[0])
    (tmp_path / "notes.txt").write_text("not a frame")
    part = tmp_path / "img_0.tif"
    part.write_bytes(data[: len(data) // 2])  # a stalled writer, halfway
    assert _poll(files, 0.4) is None  # unchanged past settle and stall: still not a frame
    part.write_bytes(data)
    path, img = _poll(files, 1.0)
    assert path == part and np.array_equal(img, frames[0])
    empty = tmp_path / "img_1.tif"
    empty.touch()  # created first, filled later
    (tmp_path / "img_2.tif").write_bytes(_tiff_bytes(frames[2]))
    assert _poll(files, 0.5) is None  # an empty file holds the later ones back
    empty.write_bytes(_tiff_bytes(frames[1]))
    assert np.array_equal(_poll(files, 1.0)[1], frames[1])
    assert np.array_equal(_poll(files, 1.0)[1], frames[2])
    assert [p.name for p in files.taken] == ["img_0.tif", "img_1.tif", "img_2.tif"]


def test_junk_matching_the_pattern_is_skipped_once_later_frames_are_complete(tmp_path,
                                                                           frames):
    files = FrameFiles(tmp_path, settle=0.05, stall=0.3)
    (tmp_path / "a_0.tif").write_bytes(_tiff_bytes(frames[0]))
    (tmp_path / "a_1.tif").write_bytes(b"\x00garbage" * 50)
    (tmp_path / "a_2.tif").write_bytes(_tiff_bytes(frames[1][:50]))  # another size
    (tmp_path / "a_3.tif").write_bytes(_tiff_bytes(frames[3]))
    (tmp_path / "a_3.tif.tmp").write_bytes(b"being written")
    assert _poll(files, 0.5)[0].name == "a_0.tif"
    path, img = _poll(files, 1.5)
    assert path.name == "a_3.tif" and np.array_equal(img, frames[3])
    assert sorted(n for n, _ in files.skipped) == ["a_1.tif", "a_2.tif"]


def _camera(folder, frames, style, interval=0.25, zero_byte=None, stall=None):
    def go():
        folder.mkdir(exist_ok=True)
        (folder / "notes.txt").write_text("junk")
        for k, img in enumerate(frames):
            if zero_byte is not None and k == zero_byte - 1:
                (folder / f"f_{zero_byte:03d}.tif").touch()
            write_frame(folder / f"f_{k:03d}.tif", img, style, chunks=3, pause=0.03,
                        stall=stall[1] if stall and stall[0] == k else 0.0)
            time.sleep(interval)
    t = threading.Thread(target=go)
    t.start()
    return t


def _reader(out, stop):
    """load_run of the run folder while the watch writes it: failures once it exists."""
    fails, seen = [], 0
    while not stop.is_set():
        try:
            seq = load_run(out)
            present = [i for i, ok in enumerate(seq.frames.present) if ok]
            _ = seq.frames[present[-1]].u
            seen = max(seen, len(present))
        except (FileNotFoundError, ValueError) as exc:
            if seen:
                fails.append(repr(exc))
        time.sleep(0.01)
    return fails, seen


@pytest.mark.slow
@pytest.mark.parametrize("style, reference, extra", [
    ("chunks", "accumulative", {"zero_byte": 3}),
    ("rename", "incremental", {"stall": (2, 0.5)}),
])
def test_watch_equals_offline_track(tmp_path, frames, style, reference, extra):
    cam, out = tmp_path / "cam", tmp_path / "run"
    writer = _camera(cam, frames, style, **extra)
    stop, result = threading.Event(), {}
    reader = threading.Thread(target=lambda: result.update(r=_reader(out, stop)))
    reader.start()
    seen = []
    try:
        rep = watch(cam, out, reference=reference, idle_timeout=1.0, settle=0.1,
                    on_frame=lambda k, res, info: seen.append((k, info["latency"])))
    finally:
        writer.join()
        stop.set()
        reader.join()
    assert rep.ended == "idle" and rep.computed == list(range(1, N)) == [k for k, _ in seen]
    fails, n_seen = result["r"]
    assert fails == [] and n_seen == N
    live, off = load_run(out), track(cam, reference=reference, out_dir=tmp_path / "off")
    for k in range(1, N):
        a, b = live[k], off[k]
        assert np.array_equal(a.valid, b.valid)
        assert np.nanmax(np.abs(a.u - b.u)) <= 1e-6 and np.nanmax(np.abs(a.v - b.v)) <= 1e-6
    assert abs(np.mean(off[N - 1].dudx[off[N - 1].valid]) - 0.004 * (N - 1)) < 1e-3


def test_live_probe_rows_wait_for_a_growing_load_file(tmp_path, frames):
    out = tmp_path / "run"
    seq = track(np.stack(frames[:3]), out_dir=out)
    load = tmp_path / "load.csv"
    load.write_text("frame,load_N\n0,0\n1,100\n")
    csv = tmp_path / "probes.csv"
    live = LiveProbes(ProbeSet(lines=[LineProbe(20, 56, 92, 56)]), csv, load=load,
                      area_mm2=10.0, sync="frame", grace=30.0)
    live.start(tmp_path / "nothing_yet")
    live.add(1, seq[1])
    live.add(2, seq[2])
    rows = csv.read_text().splitlines()
    assert len(rows) == 2 and rows[1].startswith("1,")  # frame 2 waits for its load
    with open(load, "a") as fh:
        fh.write("2,2")  # the machine is writing this line: not read yet
    live.tick()
    assert len(csv.read_text().splitlines()) == 2
    with open(load, "a") as fh:
        fh.write("00\n")
    live.tick()
    rows = csv.read_text().splitlines()
    head = rows[0].split(",")
    assert len(rows) == 3 and rows[2].split(",")[head.index("load_N")] == "200"
    assert rows[2].split(",")[head.index("stress_MPa")] == "20"
    live.close(out)  # the whole run written as `napari-aldic probe` writes it
    final = csv.read_text().splitlines()
    assert len(final) == 4 and final[0] == rows[0] and final[3] == rows[2]


def test_reference_kept_between_frames_changes_no_number(frames):
    # track keeps the reference's spline, gradients, noise, speckle quality and lags
    # between frames (correlate's solver_cache); a fresh correlate of one frame from
    # the same guess must give the very same result
    from napari_aldic.engine import correlate

    seq = track(np.stack(frames[:3]))
    fresh = correlate(frames[0], frames[2], guess=seq[1])
    for name in ("u", "v", "dudx", "dvdy", "zncc", "u_std", "sssig"):
        assert np.array_equal(getattr(fresh, name), getattr(seq[2], name), equal_nan=True), name
    assert np.array_equal(fresh.reason, seq[2].reason)
