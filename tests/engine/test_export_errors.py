"""Exports fail cleanly: bad paths, no permission, full disk; nothing half-written."""

import builtins
import errno
import os

import pytest

from napari_aldic.engine import DICParams, ExportError, Settings, export_report, write_settings
from napari_aldic.engine.io import export_csv, export_davis, export_mat, export_vtu
from napari_aldic.engine.viz import export_gif, export_mp4, export_png


def _params_writer(data, path):
    return write_settings(path, Settings(data.params))


WRITERS = {
    "csv": (export_csv, "r.csv"),
    "mat": (export_mat, "r.mat"),
    "vtu": (export_vtu, "r.vtu"),
    "davis": (export_davis, "r.txt"),
    "png": (lambda d, p: export_png(d, p, dpi=50), "r.png"),
    "gif": (lambda d, p: export_gif(d, p, dpi=50), "r.gif"),
    "pdf": (export_report, "r.pdf"),
    "params": (_params_writer, "r.json"),
}


@pytest.fixture
def one(export_sequence):
    """Frame 2 of the shared export sequence (a single DICResult)."""
    return export_sequence[2]


@pytest.mark.parametrize("fmt", sorted(WRITERS))
def test_missing_folder_is_named(tmp_path, fmt, one):
    write, name = WRITERS[fmt]
    target = tmp_path / "no" / "such" / name
    with pytest.raises(ExportError, match="does not exist") as info:
        write(one, target)
    assert str(target) in str(info.value) and "create it" in str(info.value).lower()
    assert not (tmp_path / "no").exists()


def test_parent_is_a_file_or_target_is_a_folder(tmp_path, one):
    (tmp_path / "plain").write_text("x")
    with pytest.raises(ExportError, match="is a file, not a folder"):
        export_csv(one, tmp_path / "plain" / "r.csv")
    (tmp_path / "r.csv").mkdir()
    with pytest.raises(ExportError, match="a folder of that name exists"):
        export_csv(one, tmp_path / "r.csv")


def test_permission_error_while_creating_the_file(tmp_path, monkeypatch, one):
    import tempfile

    def deny(*a, **k):
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(tempfile, "mkstemp", deny)
    with pytest.raises(ExportError, match="permission denied") as info:
        export_mat(one, tmp_path / "r.mat")
    assert "r.mat" in str(info.value)
    assert list(tmp_path.iterdir()) == []


class _FullDisk:
    """A file object whose writes fail with ENOSPC after a few bytes."""

    def __init__(self, fh, budget=64):
        self._fh = fh
        self._left = budget

    def write(self, data):
        if len(data) > self._left:
            self._fh.write(data[:self._left])  # part of it reaches the disk
            self._left = 0
            raise OSError(errno.ENOSPC, "No space left on device")
        self._left -= len(data)
        return self._fh.write(data)

    def __getattr__(self, name):
        return getattr(self._fh, name)

    def __iter__(self):
        return iter(self._fh)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._fh.close()


@pytest.fixture
def full_disk(monkeypatch):
    """Every file opened for writing under a temporary '.part' name fills the disk."""
    real_open = builtins.open

    def fake_open(file, mode="r", *args, **kwargs):
        fh = real_open(file, mode, *args, **kwargs)
        is_tmp = isinstance(file, (str, os.PathLike)) and ".part" in os.fspath(file)
        if is_tmp and any(c in mode for c in "wax+"):
            return _FullDisk(fh)
        return fh

    monkeypatch.setattr(builtins, "open", fake_open)


@pytest.mark.parametrize("fmt", sorted(WRITERS))
def test_full_disk_leaves_no_file_and_keeps_the_old_one(tmp_path, fmt, full_disk, one):
    write, name = WRITERS[fmt]
    target = tmp_path / name
    target.write_bytes(b"previous complete export")
    with pytest.raises(ExportError) as info:
        write(one, target)
    msg = str(info.value)
    assert "no space left" in msg and str(target) in msg and "free some space" in msg.lower()
    assert info.value.errno == errno.ENOSPC
    assert target.read_bytes() == b"previous complete export"  # untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # no temporary left


def test_full_disk_in_a_multi_file_export(tmp_path, full_disk, export_sequence):
    with pytest.raises(ExportError, match="no space left"):
        export_vtu(export_sequence, tmp_path / "s.vtu")
    assert list(tmp_path.iterdir()) == []  # no .pvd announcing missing frames


def test_video_encoder_failure_leaves_nothing(tmp_path, monkeypatch, export_sequence):
    import imageio_ffmpeg

    def failing_writer(path, *args, **kwargs):
        with open(path, "wb") as fh:
            fh.write(b"\x00" * 100)  # ffmpeg had started the file
        yield
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(imageio_ffmpeg, "write_frames", failing_writer)
    with pytest.raises(ExportError, match="no space left"):
        export_mp4(export_sequence, tmp_path / "u.mp4", dpi=40)
    assert list(tmp_path.iterdir()) == []


def test_interrupted_export_leaves_nothing(tmp_path, monkeypatch, one):
    import scipy.io

    def interrupted(fh, *a, **k):
        fh.write(b"MATLAB 5.0 MAT-file, partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(scipy.io, "savemat", interrupted)
    with pytest.raises(KeyboardInterrupt):
        export_mat(one, tmp_path / "r.mat")
    assert list(tmp_path.iterdir()) == []


def test_params_file_errors(tmp_path):
    with pytest.raises(ExportError, match="does not exist"):
        write_settings(tmp_path / "nope" / "p.json", Settings(DICParams()))
    with pytest.raises(TypeError, match="Settings"):
        write_settings(tmp_path / "p.json", {"subset": 21})


def test_result_save_uses_the_same_atomic_write(tmp_path, full_disk, one):
    target = tmp_path / "r.npz"
    target.write_bytes(b"previous complete result")
    with pytest.raises(ExportError, match="no space left") as info:
        one.save(target)
    assert isinstance(info.value, OSError) and info.value.errno == errno.ENOSPC
    assert target.read_bytes() == b"previous complete result"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.npz"]


def test_result_save_to_a_missing_folder_stays_file_not_found(tmp_path, one):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        one.save(tmp_path / "nope" / "r.npz")
    assert not (tmp_path / "nope").exists()


def test_sequence_manifest_is_written_atomically(tmp_path, monkeypatch, export_stack):
    from pathlib import Path

    from napari_aldic.engine import track

    def full(self, text, *args, **kwargs):
        with open(self, "w") as fh:
            fh.write(text[:10])  # part of it reaches the disk
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_text", full)
    with pytest.raises(ExportError, match="no space left"):
        track(export_stack[:2], subset=21, step=24, out_dir=tmp_path)
    assert list(tmp_path.iterdir()) == []  # no sequence.json, no temporary
