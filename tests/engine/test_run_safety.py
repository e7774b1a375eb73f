"""Runs that cannot be mixed or lost (issue 11, section 2): run-folder identity
and resume checks, the folder lock, temporaries, a bad frame keeping the
finished ones, one ROI per run."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
import tifffile

from napari_aldic.engine import (
    Refinement,
    RunFolderError,
    TrackError,
    load_result,
    load_run,
    track,
)
from napari_aldic.engine.core.files import LOCK_NAME, ExportError, atomic_write, folder_lock

FAST = {"subset": 21, "step": 24}  # a 5 x 5 lattice on the 128 px export stack


@pytest.fixture
def stack(export_stack):
    return export_stack[:3]


def _roi(shape=(128, 128), x0=10):
    m = np.zeros(shape, bool)
    m[10:118, x0:118] = True
    return m


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


# ----------------------------------------------------------------- resume refuses
@pytest.mark.parametrize("change, words", [
    ({"roi": _roi(x0=20)},
     r"the ROI changed \(11,664 px, sha256 \w{12} recorded, 10,584 px, sha256 \w{12} now\)"),
    ({"refine": "light"}, r"the refinement changed \(null recorded, \{.*mask_boundary"),
    ({"refine": Refinement(brush=_roi(x0=60))}, r"the refinement changed .*sha256"),
    ({"step": 20}, r"the parameters changed \(step 24 -> 20\)"),
    ({"seeds": [(64.0, 64.0)], "init": "seeds"},
     r"the parameters changed \(init \"fft\" -> \"seeds\", seeds \[\] -> \[\[64.0, 64.0\]\]\)"),
    ({"reference": "incremental"},
     r"the reference mode changed \(\"accumulative\" recorded, \"incremental\" now\)"),
    ({"frames": [0, 2]}, r"the analysed frames changed \(\[0, 1, 2\] recorded, \[0, 2\] now\)"),
    ({"meta": {"units": {"unit": "mm"}}}, r"the metadata stored with each frame \(e.g. units\)"),
    ({"rois": [_roi()] * 3}, r"per-frame ROIs were not given for the recorded run but are now"),
])
def test_resume_refuses_any_change_and_names_it(stack, tmp_path, change, words):
    out = tmp_path / "run"
    track(stack, roi=_roi(), out_dir=out, **FAST)
    before = _snapshot(out)
    kw = {"roi": _roi(), **FAST, **change}
    with pytest.raises(RunFolderError, match="different analysis") as err:
        track(stack, out_dir=out, **kw)
    assert re.search(words, str(err.value)) and str(out) in str(err.value)
    assert _snapshot(out) == before  # nothing written, nothing mixed
    seq = track(stack, roi=_roi(), out_dir=out, **FAST)  # the same analysis resumes
    assert seq.complete


def test_resume_refuses_a_changed_brush_region(stack, tmp_path):
    out = tmp_path / "run"
    track(stack, out_dir=out, refine=Refinement(brush=_roi(x0=60)), **FAST)
    with pytest.raises(RunFolderError, match="painted refinement region changed"):
        track(stack, out_dir=out, refine=Refinement(brush=_roi(x0=70)), **FAST)


def test_resume_refuses_changed_stack_content(stack, tmp_path):
    out = tmp_path / "run"
    track(stack, out_dir=out, **FAST)
    other = stack.copy()
    other[-1, 40, 40] ^= 1  # one pixel of the last frame
    with pytest.raises(RunFolderError, match="last analysed frame holds other pixel values"):
        track(other, out_dir=out, **FAST)


def test_resume_refuses_a_modified_image_file(stack, tmp_path):
    images = tmp_path / "images"
    images.mkdir()
    for k, img in enumerate(stack):
        tifffile.imwrite(images / f"img_{k}.tif", img)
    out = tmp_path / "run"
    track(images, out_dir=out, **FAST)
    st = os.stat(images / "img_1.tif")  # a middle frame: no digest, size and time say it
    tifffile.imwrite(images / "img_1.tif", stack[2])
    os.utime(images / "img_1.tif", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    with pytest.raises(RunFolderError, match=r"image file img_1\.tif changed since the run"):
        track(images, out_dir=out, **FAST)


def test_old_manifest_and_foreign_files_are_refused(stack, tmp_path):
    old = tmp_path / "old"  # the previous version's manifest: no ROI, stack or refine
    old.mkdir()
    (old / "sequence.json").write_text(json.dumps({"params": {}, "frames": [0, 1, 2]}))
    with pytest.raises(RunFolderError, match="earlier napari-aldic version"):
        track(stack, out_dir=old, **FAST)
    loose = tmp_path / "loose"  # result files without a manifest (e.g. the old CLI)
    loose.mkdir()
    (loose / "frame001.npz").write_bytes(b"x")
    with pytest.raises(RunFolderError, match=r"frame001\.npz\) but no sequence\.json"):
        track(stack, out_dir=loose, **FAST)
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "sequence.json").write_text("{not json")
    with pytest.raises(RunFolderError, match=r"cannot read the run manifest .*sequence\.json"):
        track(stack, out_dir=broken, **FAST)
    (broken / "sequence.json").write_text(json.dumps({"format": "napari-aldic-run",
                                                      "format_version": 99}))
    with pytest.raises(RunFolderError, match="format version 99, newer than"):
        track(stack, out_dir=broken, **FAST)
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(RunFolderError, match="a_file as a run folder: it is a file"):
        track(stack, out_dir=tmp_path / "a_file", **FAST)


def test_a_frame_file_of_another_run_is_not_mixed_in(stack, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    track(stack, out_dir=a, roi=_roi(), **FAST)
    track(stack, out_dir=b, roi=_roi(), **FAST, search=12)  # another analysis
    (a / "frame_00002.npz").write_bytes((b / "frame_00002.npz").read_bytes())
    with pytest.raises(RunFolderError, match=r"frame_00002\.npz belongs to another analysis"):
        track(stack, out_dir=a, roi=_roi(), **FAST)
    (a / "frame_00002.npz").write_bytes(b"damaged")
    with pytest.raises(RunFolderError, match=r"cannot read .*frame_00002\.npz to resume"):
        track(stack, out_dir=a, roi=_roi(), **FAST)


# ----------------------------------------------------------------- the lock
_HOLDER = """
import sys, time
from napari_aldic.engine.core.files import folder_lock
with folder_lock(sys.argv[1]):
    print("locked", flush=True)
    time.sleep(60)
"""


def test_a_second_process_is_refused_and_a_dead_owner_is_taken_over(stack, tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(out)], stdout=subprocess.PIPE,
                            text=True)
    try:
        assert proc.stdout.readline().strip() == "locked"
        with pytest.raises(RunFolderError, match="in use by another napari-aldic run") as err:
            track(stack, out_dir=out, **FAST)
        assert err.value.owner["pid"] == proc.pid
        assert f"process {proc.pid} on host {socket.gethostname()}" in str(err.value)
        assert str(out) in str(err.value)
        assert not (out / "sequence.json").exists()
    finally:
        proc.kill()
        proc.wait()
    assert (out / LOCK_NAME).exists()  # left behind by the killed process
    assert track(stack, out_dir=out, **FAST).complete  # stale (dead pid): taken over
    assert not (out / LOCK_NAME).exists()


def test_locks_of_other_hosts_and_fresh_empty_locks_are_respected(tmp_path):
    lock = tmp_path / LOCK_NAME
    lock.write_text(json.dumps({"pid": 1, "host": "elsewhere", "started": "x"}))
    with pytest.raises(RunFolderError, match="process 1 on host elsewhere"):
        with folder_lock(tmp_path):
            pass
    lock.write_text("")  # being written by a process that is starting now
    with pytest.raises(RunFolderError, match="a process that is starting now"):
        with folder_lock(tmp_path):
            pass
    old = time.time() - 3600  # an empty lock of an hour ago: its writer was killed
    os.utime(lock, (old, old))
    with folder_lock(tmp_path):
        assert json.loads(lock.read_text())["pid"] == os.getpid()
        with pytest.raises(RunFolderError, match="in use"):  # one run per folder, also
            with folder_lock(tmp_path):                      # within one process
                pass
    assert not lock.exists()


# ----------------------------------------------------------------- temporaries
def test_planted_links_are_not_followed_and_stale_temporaries_are_cleaned(stack, tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    for name in ("sequence.json.part", ".sequence.json.part", ".frame_00001.npz.abc12345.part"):
        (out / name).symlink_to(victim)
    (out / ".frame_00002.npz.k1ll3d00.part").write_bytes(b"half a frame")
    seq = track(stack, out_dir=out, **FAST)
    assert seq.complete and victim.read_text() == "precious"
    assert not [p.name for p in out.iterdir() if p.name.endswith(".part")]
    assert json.loads((out / "sequence.json").read_text())["format_version"] == 2


def test_a_temporary_swapped_for_a_link_is_never_renamed(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    target = tmp_path / "out" / "sequence.json"
    target.parent.mkdir()
    with pytest.raises(ExportError, match="was replaced by another program"):
        with atomic_write(target) as tmp:
            tmp.write_text("{}")
            tmp.unlink()
            tmp.symlink_to(victim)
    assert victim.read_text() == "precious" and list(target.parent.iterdir()) == []


# ----------------------------------------------------------------- a bad frame
def _files_with_bad(stack, folder, bad_k, kind):
    folder.mkdir()
    paths = []
    for k, img in enumerate(stack):
        p = folder / f"img_{k}.tif"
        if k == bad_k and kind == "unreadable":
            p.write_text("not an image")
        elif k == bad_k:
            tifffile.imwrite(p, img[:100, :100])
        else:
            tifffile.imwrite(p, img)
        paths.append(p)
    return paths


@pytest.mark.parametrize("kind", ["unreadable", "wrong_size"])
@pytest.mark.parametrize("scheduler", [None, "threads"])
def test_a_bad_frame_keeps_the_finished_frames(export_stack, tmp_path, kind, scheduler):
    paths = _files_with_bad(export_stack, tmp_path / "img", 2, kind)
    with pytest.raises(TrackError, match=r"frame 2 \(.*img_2\.tif\) could not be analysed") \
            as err:
        track(paths, scheduler=scheduler, workers=1, **FAST)
    part = err.value.partial
    assert err.value.frame == 2 and part.meta["failed_frame"] == 2
    assert part[0] is not None and part[1] is not None and part[2] is None
    ref = track(export_stack[:2], **FAST)
    np.testing.assert_allclose(part[1].u, ref[1].u, atol=1e-9)
    assert isinstance(err.value.__cause__, ValueError)


def test_plugin_run_keeps_frames_before_a_bad_frame(export_stack):
    from napari_aldic._analysis import run_analysis
    from napari_aldic.engine import DICParams

    class Stack:  # a lazy stack whose frame 2 cannot be read
        shape, dtype, ndim = export_stack.shape, export_stack.dtype, 3

        def __getitem__(self, key):
            if isinstance(key, slice):
                return self
            if key == 2:
                raise ValueError("cannot read frame 2: truncated file")
            return export_stack[key]

        def __len__(self):
            return self.shape[0]

    messages = []
    analysis = run_analysis(Stack(), None, DICParams(**FAST),
                            progress=lambda ev: messages.append(str(ev)))
    assert analysis.n_done == 2 and analysis.results[2] is None
    assert "truncated file" in analysis.error and analysis.strains[1] is not None
    assert any("done" in m and "truncated file" in m for m in messages)  # shown in the log


# ----------------------------------------------------------------- one ROI per run
def test_frames_share_one_roi_stored_once(stack, tmp_path):
    out = tmp_path / "run"
    seq = track(stack, out_dir=out, roi=_roi(), **FAST)
    assert seq[1].roi is seq[2].roi  # one array per run in memory
    rois = sorted(out.glob("roi_*.npz"))
    assert len(rois) == 1
    with np.load(out / "frame_00002.npz") as z:
        assert "roi_packed" not in z.files
    back = load_run(out)
    assert back[1].roi is back[2].roi
    np.testing.assert_array_equal(back[2].roi, _roi())
    whole = track(stack, **FAST)  # no ROI: still one shared array, not one per frame
    assert whole[1].roi is whole[2].roi
    lone = tmp_path / "lone.npz"  # a frame copied out of its run folder: named error
    lone.write_bytes((out / "frame_00002.npz").read_bytes())
    with pytest.raises(ValueError, match=r"the ROI file .*roi_.*\.npz that this result refers"):
        load_result(lone)
    rois[0].write_bytes(rois[0].read_bytes()[:-40])
    with pytest.raises(ValueError, match=r"cannot read the ROI file"):
        load_result(out / "frame_00001.npz")
