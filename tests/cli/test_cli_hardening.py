"""Issue 23 on the command line: FIFOs refused (never a hang), edited results not
exported as trusted, ``--to ""`` refused, an output under a file named, and Ctrl-C
at any moment of the start-up one line and exit code 130."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import tifffile

from napari_aldic.engine import correlate, synthetic as S


def _one_error_line(rc, err, pattern):
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("napari-aldic: error: ") and pattern in lines[0], lines[0]


def _within(run_cli, argv, seconds=60.0):
    """``run_cli(argv)`` in a thread: a reader blocked on a FIFO fails the test."""
    out = {}
    t = threading.Thread(target=lambda: out.update(r=run_cli(argv)), daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), f"napari-aldic {argv} blocked"
    return out["r"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cli_hardening")
    ref, dfm = S.speckle_pair((96, 96), S.Translation(0.5, 0.25), seed=4)
    tifffile.imwrite(tmp / "ref.tif", ref)
    tifffile.imwrite(tmp / "def.tif", dfm)
    res = correlate(ref, dfm, subset=21, step=16)
    good = res.save(tmp / "good.npz")
    with np.load(good) as z:
        arrays = dict(z)
    arrays["u"] = arrays["u"].copy()
    arrays["u"][np.nonzero(arrays["valid"])[0][0]] = np.nan  # edited by hand
    np.savez(tmp / "edited.npz", **arrays)
    if hasattr(os, "mkfifo"):
        os.mkfifo(tmp / "p.fifo")
    (tmp / "afile").write_text("x")
    return tmp


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
@pytest.mark.parametrize("argv", [
    ["run", "{t}/ref.tif", "{t}/def.tif", "--params", "{t}/p.fifo", "-o", "{t}/o1"],
    ["run", "{t}/ref.tif", "{t}/p.fifo", "-o", "{t}/o2"],
    ["run", "{t}/ref.tif", "{t}/def.tif", "--roi", "{t}/p.fifo", "-o", "{t}/o3"],
    ["export", "{t}/p.fifo", "--to", "csv"],
], ids=["params", "image", "roi", "result"])
def test_a_fifo_is_refused_not_waited_on(run_cli, files, argv):
    rc, _, err = _within(run_cli, [a.format(t=files) for a in argv])
    _one_error_line(rc, err, "named pipe (FIFO)")


def test_edited_results_and_empty_formats_are_refused(run_cli, files, tmp_path):
    rc, _, err = run_cli(["export", files / "edited.npz", "--to", "csv", "-o", tmp_path / "e"])
    _one_error_line(rc, err, "marked valid but their 'u' is not a finite number")
    assert list(tmp_path.iterdir()) == []
    rc, _, err = run_cli(["export", files / "good.npz", "--to", "", "-o", tmp_path / "e"])
    _one_error_line(rc, err, "no export format given")


def test_a_damaged_tiff_of_a_pair_is_one_line(run_cli, files, tmp_path):
    raw = (files / "ref.tif").read_bytes()
    bad = tmp_path / "bad.tif"
    bad.write_bytes(raw[:4] + b"\xff\xff\x00\x01" + raw[8:])  # offset of the first page
    rc, _, err = run_cli(["run", bad, files / "def.tif", "-o", tmp_path / "out", "--subset",
                          21, "--step", 16])
    _one_error_line(rc, err, f"cannot read image {bad}: it is damaged")


def test_an_output_under_a_file_is_named(run_cli, files):
    rc, _, err = run_cli(["run", files / "ref.tif", files / "def.tif", "-o",
                          files / "afile" / "sub" / "out", "--subset", 21, "--step", 16])
    _one_error_line(rc, err, f"{files / 'afile'} is a file, not a folder")


@pytest.mark.slow
@pytest.mark.skipif(os.name == "nt", reason="SIGINT to a child process is POSIX")
def test_ctrl_c_during_the_start_up_is_one_line_and_130(files):
    """Ctrl-C at several moments of the first seconds (Python starting, NumPy and the
    engine importing, the command running): one line and 130 each time."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [os.path.dirname(os.path.dirname(__import__("napari_aldic").__file__)),
         os.environ.get("PYTHONPATH", "")])}
    argv = [sys.executable, "-m", "napari_aldic.cli", "run", str(files / "ref.tif"),
            str(files / "def.tif"), "-o", str(files / "ctrlc"), "--subset", "21"]
    for delay in (0.15, 0.4, 0.8, 1.5, 3.0):
        proc = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
        if proc.returncode == 0:  # finished before the signal: nothing to check
            continue
        assert proc.returncode == 130, (delay, proc.returncode, err)
        lines = err.strip().splitlines()
        assert lines == ["napari-aldic: interrupted (results already written are kept)"], \
            (delay, err)
