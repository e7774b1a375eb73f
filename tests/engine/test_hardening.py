"""Issue 23: no file, path or interruption makes napari-aldic lie, hang or lose a run.

Each test here failed before the fix it names: result files whose invariants were
edited, FIFOs that blocked the readers, links written through, damaged field stores,
changed frames resumed, empty locks, half-written export sets, hostile manifests and
projects, load CSVs and the argument checks of ``correlate`` and ``track``. The kill
test (SIGKILL at several moments of a run) is in test_kill_resume.py, the fuzz test
of the readers in test_fuzz_readers.py, the command line in
tests/cli/test_cli_hardening.py.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import threading
import zipfile

import numpy as np
import pytest

from napari_aldic.engine import (
    ExportError,
    InputFileError,
    RunFolderError,
    correlate,
    load_result,
    load_run,
    synthetic as S,
    track,
)
from napari_aldic.engine.core import files as F
from napari_aldic.engine.io import export_vtu, open_stack, read_image, read_settings
from napari_aldic.engine.probes import read_load_csv

FAST = {"subset": 21, "step": 24}


def _within(fn, seconds: float = 20.0):
    """Run ``fn`` in a thread; fail (not hang) when it blocks, e.g. on a FIFO."""
    out: dict = {}

    def target():
        try:
            out["value"] = fn()
        except BaseException as exc:  # handed to the test
            out["error"] = exc

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), "the reader blocked (it opened a FIFO)"
    if "error" in out:
        raise out["error"]
    return out.get("value")


@pytest.fixture(scope="module")
def pair():
    return S.speckle_pair((96, 96), S.Translation(0.4, -0.2), seed=1)


@pytest.fixture(scope="module")
def stack(pair):
    pat = S.make_pattern((96, 96), seed=3, margin=24)
    return np.stack([S.render(pat, (96, 96), None if k == 0 else
                              S.Translation(0.3 * k, -0.2 * k), n_quad=2, seed=k)
                     for k in range(4)]).astype(np.float32)


@pytest.fixture(scope="module")
def result(pair):
    return correlate(*pair, **FAST)


# ----------------------------------------------------------------- FIFOs
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
def test_fifos_are_refused_before_they_are_opened(tmp_path):
    fifo = tmp_path / "p.fifo"
    os.mkfifo(fifo)
    readers = {"result": lambda: load_result(fifo), "params": lambda: read_settings(fifo),
               "image": lambda: read_image(fifo), "stack": lambda: open_stack(fifo),
               "load csv": lambda: read_load_csv(fifo),
               "json": lambda: F.read_json_file(fifo, "settings")}
    (tmp_path / "run").mkdir()
    os.mkfifo(tmp_path / "run" / "sequence.json")
    readers["manifest"] = lambda: load_run(tmp_path / "run")
    for name, read in readers.items():
        with pytest.raises(ValueError, match=r"named pipe \(FIFO\)") as info:
            _within(read)
        assert "p.fifo" in str(info.value) or "sequence.json" in str(info.value), name
    with pytest.raises(FileNotFoundError):
        F.regular_file(tmp_path / "missing.json")


# ----------------------------------------------------------------- result invariants
def _edited(result, tmp_path, **change):
    """``result`` saved, then its arrays edited in the file (as by hand)."""
    path = result.save(tmp_path / "r.npz")
    with np.load(path) as z:
        arrays = dict(z)
    i = int(np.nonzero(arrays["valid"])[0][0])
    for name, value in change.items():
        arrays[name] = arrays[name].copy()
        arrays[name][i] = value
    edited = tmp_path / "edited.npz"
    np.savez(edited, **arrays)
    return edited


@pytest.mark.parametrize("change, words", [
    ({"u": np.nan}, r"marked valid but their 'u' is not a finite number"),
    ({"v": np.inf}, r"marked valid but their 'v' is not a finite number"),
    ({"reason": 5}, r"marked valid but carry a failure reason .*reason 5"),
])
def test_edited_results_are_not_trusted(result, tmp_path, change, words):
    edited = _edited(result, tmp_path, **change)
    with pytest.raises(ValueError, match=words) as info:
        load_result(edited)
    assert str(edited) in str(info.value)


def test_a_result_declaring_more_than_available_memory_is_named(result, tmp_path,
                                                                monkeypatch):
    path = result.save(tmp_path / "r.npz")
    monkeypatch.setattr("napari_aldic.engine.core.npzfile.available_memory", lambda: 1000)
    with pytest.raises(ValueError, match=r"more than the memory available now") as info:
        load_result(path)
    assert str(path) in str(info.value)


def test_a_result_with_an_encrypted_member_is_named(result, tmp_path):
    # zipfile raises RuntimeError ("password required") for a member flagged
    # encrypted; the seeded fuzz test met it once, as an obscure error
    data = bytearray(result.save(tmp_path / "r.npz").read_bytes())
    at = data.find(b"PK\x01\x02")  # the first central-directory entry
    data[at + 8] |= 1  # its general-purpose flag: encrypted
    bad = tmp_path / "encrypted.npz"
    bad.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="damaged") as info:
        load_result(bad)
    assert str(bad) in str(info.value)


# ----------------------------------------------------------------- run folders
def test_nothing_is_written_through_a_link_at_the_field_store(stack, tmp_path):
    out, outside = tmp_path / "run", tmp_path / "outside"
    out.mkdir()
    outside.mkdir()
    (out / "fields.zarr").symlink_to(outside, target_is_directory=True)
    with pytest.raises(RunFolderError, match=r"fields\.zarr is a link"):
        track(stack, out_dir=out, **FAST)
    assert list(outside.iterdir()) == []


def _finished(stack, folder):
    return track(stack, out_dir=folder, **FAST)


def test_a_link_inside_the_field_store_is_not_written_through(stack, tmp_path):
    out, outside = tmp_path / "run", tmp_path / "outside"
    _finished(stack, out)
    outside.mkdir()
    shutil.rmtree(out / "fields.zarr" / "u")
    (out / "fields.zarr" / "u").symlink_to(outside, target_is_directory=True)
    (out / "frame_00003.npz").unlink()
    track(stack, out_dir=out, **FAST)  # the store is rebuilt, the link removed
    assert list(outside.iterdir()) == []
    assert not (out / "fields.zarr" / "u").is_symlink()
    doc = json.loads((out / "sequence.json").read_text())
    assert sorted(doc["frame_sha256"]) == ["0", "1", "2", "3"]  # kept in the manifest too
    assert doc["frame_sha256"]["2"] == F.array_digest(stack[2])


@pytest.mark.parametrize("damage", ["missing array", "corrupt chunk", "foreign attrs",
                                    "half built"])
def test_a_damaged_field_store_is_rebuilt_from_the_frame_files(stack, tmp_path, damage):
    import zarr

    out = tmp_path / "run"
    first = _finished(stack, out)
    store = out / "fields.zarr"
    if damage == "missing array":
        shutil.rmtree(store / "done")
    elif damage == "corrupt chunk":
        chunk = next(p for p in sorted((store / "u").rglob("*"))
                     if p.is_file() and p.name != "zarr.json")
        chunk.write_bytes(b"\x28\xb5\x2f\xfd garbage")
    elif damage == "foreign attrs":
        doc = json.loads((store / "zarr.json").read_text())
        doc["attributes"]["frames"] = [0, 1]
        (store / "zarr.json").write_text(json.dumps(doc))
    else:  # killed while zarr.json was being written the old way
        for p in store.iterdir():
            if p.name != "zarr.json":
                shutil.rmtree(p)
    again = track(stack, out_dir=out, **FAST)
    g = zarr.open_group(str(store), mode="r")
    assert bool(np.all(g["done"][:]))
    for k in range(1, len(stack)):
        np.testing.assert_allclose(again[k].u, first[k].u, atol=1e-12)
        np.testing.assert_allclose(g["u"][k], first[k].to_grid("u", invalid=None),
                                   atol=1e-12, equal_nan=True)


def test_a_changed_middle_frame_is_refused_naming_it(stack, tmp_path):
    import tifffile

    tif = tmp_path / "stack.tif"
    tifffile.imwrite(tif, stack, photometric="minisblack")
    out = tmp_path / "run"
    track(tif, out_dir=out, **FAST)
    (out / "frame_00003.npz").unlink()  # as if killed before the last frame
    st = os.stat(tif)
    changed = stack.copy()
    changed[2] = np.roll(changed[2], 1, axis=1)  # same size: only the pixels differ
    tifffile.imwrite(tif, changed, photometric="minisblack")
    os.utime(tif, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert os.stat(tif).st_size == st.st_size
    with pytest.raises(RunFolderError, match=r"frame 2 .* has changed since it was analysed"):
        track(tif, out_dir=out, **FAST)
    assert not (out / "frame_00003.npz").exists()  # nothing mixed in


def test_a_bit_flipped_finished_frame_is_refused_when_resuming(stack, tmp_path):
    out = tmp_path / "run"
    _finished(stack, out)
    path = out / "frame_00002.npz"
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo("u.npy")
    raw = bytearray(path.read_bytes())
    raw[info.header_offset + 30 + len(info.filename) + 60] ^= 0x10  # inside u's data
    st = os.stat(path)
    path.write_bytes(bytes(raw))
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))  # the store would trust it
    with pytest.raises(RunFolderError, match=r"cannot read .*frame_00002\.npz to resume the "
                                             r"run: .*damaged") as info:
        track(stack, out_dir=out, **FAST)
    assert "frame 2 again" in str(info.value)


def test_a_hand_edited_manifest_is_named(stack, tmp_path):
    out = tmp_path / "run"
    _finished(stack, out)
    doc = json.loads((out / "sequence.json").read_text())
    for bad in ({**doc, "frames": "abc"}, [1, 2], {**doc, "params": [1]}):
        (out / "sequence.json").write_text(json.dumps(bad))
        with pytest.raises(ValueError, match=r"sequence\.json.*(damaged or hand-edited)"):
            load_run(out)


def test_a_full_disk_while_locking_leaves_no_lock(tmp_path, monkeypatch):
    real = os.write

    def full(fd, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "write", full)
    with pytest.raises(ExportError, match="no space left"):
        with F.folder_lock(tmp_path):
            pass
    monkeypatch.setattr(os, "write", real)
    assert list(tmp_path.iterdir()) == []  # no empty lock blocking the next run
    with F.folder_lock(tmp_path):
        assert (tmp_path / F.LOCK_NAME).read_text().startswith("{")


# ----------------------------------------------------------------- exports
def test_a_failing_frame_leaves_no_partial_vtu_set(tmp_path, monkeypatch, stack):
    from napari_aldic.engine.io import vtk

    seq = track(stack[:4], **FAST)
    calls = []

    class Full:
        def __init__(self, fh):
            self.fh = fh

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

        def write(self, text):
            raise OSError(errno.ENOSPC, "No space left on device")

    def third_fails(file, *a, **k):  # the disk fills up while the third frame is written
        calls.append(file)
        fh = open(file, *a, **k)
        return Full(fh) if len(calls) == 3 else fh

    monkeypatch.setattr(vtk, "open", third_fails, raising=False)
    with pytest.raises(ExportError, match="no space left"):
        export_vtu(seq, tmp_path / "s.vtu", strain=False)
    assert list(tmp_path.iterdir()) == []  # neither frame files nor .pvd


def test_a_library_error_on_a_full_disk_is_called_a_full_disk(tmp_path, monkeypatch):
    import zlib

    monkeypatch.setattr(shutil, "disk_usage", lambda p: shutil._ntuple_diskusage(10, 10, 0))
    with pytest.raises(ExportError, match="no space left"):
        with F.atomic_write(tmp_path / "r.pdf") as tmp:
            tmp.write_bytes(b"%PDF")
            raise zlib.error("Error -2 while flushing")
    assert list(tmp_path.iterdir()) == []


def test_an_output_under_a_file_names_the_file(tmp_path, result):
    (tmp_path / "afile").write_text("x")
    with pytest.raises(ExportError, match=r"afile is a file, not a folder"):
        result.save(tmp_path / "afile" / "sub" / "r.npz")


# ----------------------------------------------------------------- arguments
def test_bad_correlate_and_track_arguments_are_named(pair, tmp_path):
    ref, dfm = pair
    with pytest.raises(TypeError, match=r"ROI is a file name \('/x\.tif'\)"):
        correlate(ref, dfm, roi="/x.tif", **FAST)
    with pytest.raises(TypeError, match=r"reference image is a file name"):
        correlate("a.tif", dfm, **FAST)
    with pytest.raises(ValueError, match=r"smooth=1e\+300 must be 'auto' or a length"):
        correlate(ref, dfm, method="aldic", smooth=1e300, **FAST)
    with pytest.raises(ValueError, match=r"frame 1 is 60 x 60 pixels, but frame 0 is 96 x 96"):
        track([ref, dfm[:60, :60]], **FAST)
    with pytest.raises(ValueError, match=r"scheduler='gpu' must be None, 'threads'"):
        track([ref, dfm], scheduler="gpu", out_dir=tmp_path / "never", **FAST)
    assert not (tmp_path / "never").exists()
    res = correlate(ref, dfm, params={"subset": 21, "step": 24})  # a dict of the fields
    assert (res.params.subset, res.params.step) == (21, 24)
    with pytest.raises(TypeError, match="params must be a DICParams"):
        correlate(ref, dfm, params=[21])


def test_hostile_json_is_named(tmp_path):
    for name, raw, words in (("deep.json", b"[" * 200_000 + b"]" * 200_000, "too deeply"),
                             ("int.json", b'{"subset": ' + b"9" * 5000 + b"}",
                              "cannot be read"),
                             ("u16.json", "{}".encode("utf-16"), "not UTF-8")):
        p = tmp_path / name
        p.write_bytes(raw)
        with pytest.raises(InputFileError, match=words) as info:
            read_settings(p)
        assert str(p) in str(info.value)


@pytest.mark.parametrize("body, words", [
    ("t (s),load (kN),frame\n0,1,0\n1,abc,1\n2,3,2\n3,4,3\n", r"row 3: 'abc' is not a number"),
    ("t (s),load (kN),frame\n0,1,0\n1,2,1\nt (s),load (kN),frame\n2,3,2\n3,4,3\n",
     r"row 4 repeats the header row"),
    ("t (s),load (kN),frame\n0,1,0\n1,inf,1\n2,3,2\n3,4,3\n", r"'inf' is not a finite number"),
])
def test_load_csvs_with_hostile_rows_are_named(tmp_path, body, words):
    p = tmp_path / "load.csv"
    p.write_text(body)
    with pytest.raises(ValueError, match=words) as info:
        read_load_csv(p)
    assert str(p) in str(info.value)


def test_a_utf16_load_csv_is_read(tmp_path):
    p = tmp_path / "load.csv"
    p.write_text("time (s),load (kN),frame\n0,1,0\n1,2,1\n2,3,2\n", encoding="utf-16")
    rec = read_load_csv(p)
    np.testing.assert_allclose(rec.load_N, [1000, 2000, 3000])


def test_damaged_tiff_headers_are_named(tmp_path, stack):
    import tifffile

    good = tmp_path / "s.tif"
    tifffile.imwrite(good, stack, photometric="minisblack")
    raw = good.read_bytes()
    for off in (4, 10):
        bad = tmp_path / f"bad{off}.tif"
        bad.write_bytes(raw[:off] + b"\xff\xff\x00\x01" + raw[off + 4:])
        with pytest.raises(ValueError, match=r"damaged") as info:
            open_stack(bad)[1]
        assert str(bad) in str(info.value)
        assert "IndexError: tuple" not in str(info.value)


# ----------------------------------------------------------------- projects (no Qt)
def _image_layer(path, data):
    import types

    return types.SimpleNamespace(name="img", metadata={}, data=data, multiscale=False,
                                 source=types.SimpleNamespace(path=path, sample=None),
                                 scale=(1.0, 1.0), translate=(0.0, 0.0))


def test_project_image_paths_resolve_against_the_project_file(tmp_path, monkeypatch, pair):
    import tifffile

    from napari_aldic._qt.project import image_record, read_project, write_project

    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    tifffile.imwrite(a / "img.tif", pair[0])
    tifffile.imwrite(b / "img.tif", pair[1])  # same name, other pixels
    monkeypatch.chdir(a)  # the image was opened as "img.tif"
    doc = {"image": image_record(_image_layer("img.tif", pair[0])), "layers": []}
    project = write_project(a / "proj.json", doc)
    assert json.loads(project.read_text())["image"]["path"] == "img.tif"  # relative to it
    monkeypatch.chdir(b)  # opened from another folder: still a's image
    assert read_project(project)["image"]["path"] == str(a / "img.tif")
    moved = tmp_path / "c"
    shutil.copytree(a, moved)  # the project moved with its image: found beside it
    assert read_project(moved / "proj.json")["image"]["path"] == str(moved / "img.tif")
    changed = pair[0].copy()
    changed[0, 0] += 1  # same size, other content
    tifffile.imwrite(a / "img.tif", changed)
    with pytest.raises(ValueError, match=r"has changed since the project was saved \(sha256"):
        read_project(project)
    tifffile.imwrite(a / "img.tif", pair[0][:50])
    with pytest.raises(ValueError, match=r"has changed since the project was saved \(size"):
        read_project(project)


@pytest.mark.parametrize("edit, key", [
    (lambda d: d.update(layers=5), "layers"),
    (lambda d: d["layers"][0].pop("scale"), "scale"),
    (lambda d: d["layers"][0].pop("shape_type"), "shape_type"),
    (lambda d: d["layers"][0].pop("name"), "name"),
    (lambda d: d["layers"][0].update(data=[[["a", "b"], [1, 2], [3, 4]]]), "data"),
    (lambda d: d["layers"][1].update(data=[1, 2, 3, 4, 5]), "data"),
    (lambda d: d["layers"][2]["data"].update(shape=[1 << 20, 1 << 16]), "64.0 GiB"),
])
def test_malformed_projects_are_named(tmp_path, edit, key):
    from napari_aldic._qt.project import encode_array, read_project, write_project

    (tmp_path / "img.tif").write_bytes(b"II*\x00")
    doc = {"image": {"name": "img", "path": str(tmp_path / "img.tif")},
           "layers": [{"role": "roi_add", "type": "shapes", "name": "roi", "scale": [1, 1],
                       "translate": [0, 0], "data": [[[0, 0], [0, 5], [5, 5]]],
                       "shape_type": ["polygon"], "edge_width": [1.0]},
                      {"role": "seeds", "type": "points", "name": "s", "scale": [1, 1],
                       "translate": [0, 0], "data": [[1, 2]]},
                      {"role": "brush", "type": "labels", "name": "b", "scale": [1, 1],
                       "translate": [0, 0], "data": encode_array(np.zeros((4, 4), np.uint8))}]}
    path = write_project(tmp_path / "p.json", doc)
    bad = json.loads(path.read_text())
    edit(bad)
    path.write_text(json.dumps(bad))
    with pytest.raises(ValueError, match=key) as info:
        _within(lambda: read_project(path), 10)
    assert str(path) in str(info.value)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
def test_the_napari_reader_does_not_wait_on_a_fifo(tmp_path):
    from napari_aldic._reader import get_reader

    for name in ("p.npz", "p.tif"):
        os.mkfifo(tmp_path / name)
        assert _within(lambda p=tmp_path / name: get_reader(p), 10) is None


def test_a_full_disk_during_a_run_is_named_and_leaves_no_lock(stack, tmp_path, monkeypatch):
    from napari_aldic.engine.io.zarrstore import FieldStore

    def full(self, i, res):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(FieldStore, "write", full)
    with pytest.raises(ExportError, match=r"fields\.zarr: no space left on the device"):
        track(stack, out_dir=tmp_path / "run", **FAST)
    assert not (tmp_path / "run" / F.LOCK_NAME).exists()
