"""``napari-aldic watch`` (issue 26): Ctrl+C in the middle, the same command resumes,
the result equals ``napari-aldic run`` of the folder; option errors."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from napari_aldic.engine import load_run
from napari_aldic.engine.synthetic.camera import render_frames, write_frame

SRC = Path(__file__).resolve().parents[2] / "src"


def _watch(cam, out, *extra):
    env = {**os.environ, "PYTHONPATH": str(SRC), "NAPARI_ALDIC_LANGUAGE": "en"}
    return subprocess.Popen([sys.executable, "-m", "napari_aldic.cli", "watch", str(cam),
                             "-o", str(out), "--settle", "0.1", *map(str, extra)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)


@pytest.mark.slow
def test_sigint_stops_cleanly_and_the_same_command_resumes(tmp_path, run_cli):
    frames = render_frames(6, (96, 96), rate=0.004, drift=0.4)
    cam, out = tmp_path / "cam", tmp_path / "run"
    cam.mkdir()
    for k in range(3):
        write_frame(cam / f"img_{k}.tif", frames[k], "rename")
    proc = _watch(cam, out)
    end = time.monotonic() + 120
    while not (out / "frame_00002.npz").exists() and time.monotonic() < end:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    text, _ = proc.communicate(timeout=60)
    assert proc.returncode == 130, text
    assert "frame 2:" in text and len(load_run(out).frames) == 3
    assert not (out / ".napari-aldic.lock").exists()
    for k in range(3, 6):
        write_frame(cam / f"img_{k}.tif", frames[k], "chunks")
    proc = _watch(cam, out, "--idle-timeout", 0.5)
    text, _ = proc.communicate(timeout=120)
    assert proc.returncode == 0, text
    assert "frame 2:" not in text and "frame 5:" in text
    assert "3 frame(s) analysed, 2 resumed" in text
    rc, _, err = run_cli(["run", cam, "-o", tmp_path / "offline"])
    assert rc == 0, err
    live, off = load_run(out), load_run(tmp_path / "offline")
    for k in range(1, 6):
        assert np.nanmax(np.abs(live[k].u - off[k].u)) <= 1e-6
        assert np.nanmax(np.abs(live[k].v - off[k].v)) <= 1e-6


def test_watch_option_errors(tmp_path, run_cli):
    rc, _, err = run_cli(["watch", tmp_path, "-o", tmp_path / "r", "--line", 1, 2, 3, 4])
    assert rc == 2 and "--probe-csv" in err
    rc, _, err = run_cli(["watch", tmp_path, "-o", tmp_path / "r", "--load", "l.csv"])
    assert rc == 2 and "--probe-csv and --load go with probes" in err
    rc, _, err = run_cli(["watch", tmp_path, "-o", tmp_path / "r", "--idle-timeout", -1])
    assert rc == 2 and "--idle-timeout -1.0" in err
    rc, _, err = run_cli(["watch", tmp_path])
    assert rc == 2 and "-o RUN_DIR" in err
