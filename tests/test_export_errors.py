"""Exports fail cleanly: bad paths, no permission, full disk; nothing half-written."""

import builtins
import errno
import os

import pytest

from napari_aldic.engine import DICParams
from napari_aldic.engine import ExportError, save_params
from napari_aldic.engine.io import export_csv, export_davis, export_mat, export_vtu
from napari_aldic.engine.viz import export_gif, export_mp4, export_png
from napari_aldic.engine import export_report

from _export_data import sequence


def _params_writer(data, path):
    return save_params(path, data.params)


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


def _one():
    return sequence()[2]


@pytest.mark.parametrize("fmt", sorted(WRITERS))
def test_missing_folder_is_named(tmp_path, fmt):
    write, name = WRITERS[fmt]
    target = tmp_path / "no" / "such" / name
    with pytest.raises(ExportError, match="does not exist") as info:
        write(_one(), target)
    assert str(target) in str(info.value) and "create it" in str(info.value).lower()
    assert not (tmp_path / "no").exists()


def test_parent_is_a_file_or_target_is_a_folder(tmp_path):
    (tmp_path / "plain").write_text("x")
    with pytest.raises(ExportError, match="is a file, not a folder"):
        export_csv(_one(), tmp_path / "plain" / "r.csv")
    (tmp_path / "r.csv").mkdir()
    with pytest.raises(ExportError, match="a folder of that name exists"):
        export_csv(_one(), tmp_path / "r.csv")


def test_permission_error_while_creating_the_file(tmp_path, monkeypatch):
    import tempfile

    def deny(*a, **k):
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(tempfile, "mkstemp", deny)
    with pytest.raises(ExportError, match="permission denied") as info:
        export_mat(_one(), tmp_path / "r.mat")
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
def test_full_disk_leaves_no_file_and_keeps_the_old_one(tmp_path, fmt, full_disk):
    write, name = WRITERS[fmt]
    target = tmp_path / name
    target.write_bytes(b"previous complete export")
    with pytest.raises(ExportError) as info:
        write(_one(), target)
    msg = str(info.value)
    assert "no space left" in msg and str(target) in msg and "free some space" in msg.lower()
    assert info.value.errno == errno.ENOSPC
    assert target.read_bytes() == b"previous complete export"  # untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # no temporary left


def test_full_disk_in_a_multi_file_export(tmp_path, full_disk):
    with pytest.raises(ExportError, match="no space left"):
        export_vtu(sequence(), tmp_path / "s.vtu")
    assert list(tmp_path.iterdir()) == []  # no .pvd announcing missing frames


def test_video_encoder_failure_leaves_nothing(tmp_path, monkeypatch):
    import imageio_ffmpeg

    def failing_writer(path, *args, **kwargs):
        with open(path, "wb") as fh:
            fh.write(b"\x00" * 100)  # ffmpeg had started the file
        yield
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(imageio_ffmpeg, "write_frames", failing_writer)
    with pytest.raises(ExportError, match="no space left"):
        export_mp4(sequence(), tmp_path / "u.mp4", dpi=40)
    assert list(tmp_path.iterdir()) == []


def test_interrupted_export_leaves_nothing(tmp_path, monkeypatch):
    import scipy.io

    def interrupted(fh, *a, **k):
        fh.write(b"MATLAB 5.0 MAT-file, partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(scipy.io, "savemat", interrupted)
    with pytest.raises(KeyboardInterrupt):
        export_mat(_one(), tmp_path / "r.mat")
    assert list(tmp_path.iterdir()) == []


def test_params_file_errors(tmp_path):
    with pytest.raises(ExportError, match="does not exist"):
        save_params(tmp_path / "nope" / "p.json", DICParams())
    with pytest.raises(TypeError, match="DICParams"):
        save_params(tmp_path / "p.json", {"subset": 21})
