"""Every error of the command line is one line and exit code 2, never a
traceback (issue 11, section 3); ``NAPARI_ALDIC_DEBUG=1`` adds the traceback."""

from __future__ import annotations

import re
import zipfile

import numpy as np
import pytest
import tifffile

from napari_aldic.cli import app
from napari_aldic.engine import correlate, synthetic as S
from napari_aldic.engine.io import read_csv

SHAPE = (96, 96)




def _one_error_line(rc, err, pattern, name=None):
    assert rc == 2, err
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("napari-aldic: error: "), err
    assert re.search(pattern, lines[0]), lines[0]
    if name is not None:
        assert name in lines[0], lines[0]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A pair of images, a good result file and a set of bad inputs."""
    tmp = tmp_path_factory.mktemp("cli_errors")
    ref, dfm = S.speckle_pair(SHAPE, S.Translation(0.5, 0.25), seed=4)
    tifffile.imwrite(tmp / "ref.tif", ref)
    tifffile.imwrite(tmp / "def.tif", dfm)
    good = correlate(ref, dfm, subset=21, step=12).save(tmp / "good.npz")
    (tmp / "empty.npz").write_bytes(b"")
    (tmp / "notes.npz").write_text("u,v\n1,2\n")
    data = good.read_bytes()
    (tmp / "cut.npz").write_bytes(data[: len(data) // 2])
    with zipfile.ZipFile(good) as zin, zipfile.ZipFile(tmp / "nox.npz", "w") as zout:
        for info in zin.infolist():
            if info.filename != "x.npy":
                zout.writestr(info, zin.read(info))
    with tifffile.TiffWriter(tmp / "stack.tif") as tw:
        for img in (ref, dfm, dfm):
            tw.write(img, contiguous=False, metadata=None)
    stack = (tmp / "stack.tif").read_bytes()
    (tmp / "cut.tif").write_bytes(stack[:-3000])
    mixed = tmp / "mixed"
    mixed.mkdir()
    for k, img in enumerate((ref, dfm, dfm[:80])):
        tifffile.imwrite(mixed / f"img_{k}.tif", img)
    for name, text in {"seeds.json": '{"seeds": [[1]]}', "seeds5.json": '{"seeds": 5}',
                       "threads.json": '{"n_threads": "4"}', "mu.json": '{"mu": "0.1"}',
                       "units.json": '{"params": {}, "units": 5}',
                       "nan.json": '{"zncc_rel": NaN}'}.items():
        (tmp / name).write_text(text)
    return tmp


PARAM_CASES = {
    "seeds.json": r"seed 0 .* two numbers", "seeds5.json": r"seeds=5 must be a list",
    "threads.json": r"n_threads='4' must be an integer", "mu.json": r"mu='0.1' must be a number",
    "units.json": r"'units' section must be a JSON object",
    "nan.json": r"zncc_rel=nan must be a finite number",
}


@pytest.mark.parametrize("name", sorted(PARAM_CASES))
def test_run_with_a_bad_params_file(run_cli, files, name):
    rc, _, err = run_cli(["run", files / "ref.tif", files / "def.tif", "--params", files / name,
                       "-o", files / "out.npz"])
    _one_error_line(rc, err, PARAM_CASES[name], name)


EXPORT_CASES = {
    "empty.npz": r"the file is empty \(0 bytes\)",
    "notes.npz": r"it is a text file, not an \.npz archive",
    "cut.npz": r"truncated or damaged",
    "nox.npz": r"array\(s\) \['x'\] are missing",
}


@pytest.mark.parametrize("name", sorted(EXPORT_CASES))
def test_export_of_a_bad_result_file(run_cli, files, tmp_path, name):
    rc, _, err = run_cli(["export", files / name, "--to", "csv", "-o", tmp_path / "out.csv"])
    _one_error_line(rc, err, EXPORT_CASES[name], name)
    assert not (tmp_path / "out.csv").exists()


def test_run_on_a_truncated_tiff(run_cli, files, tmp_path):
    rc, _, err = run_cli(["run", files / "cut.tif", "-o", tmp_path / "run"])
    _one_error_line(rc, err, r"truncated: page 2 of 3", "cut.tif")


def test_run_on_a_folder_of_mixed_sizes(run_cli, files, tmp_path):
    rc, _, err = run_cli(["run", files / "mixed", "-o", tmp_path / "run", "--step", "24"])
    _one_error_line(rc, err, r"is 80 x 96 pixels, but img_0\.tif", "img_2.tif")


def test_huge_search_is_clipped_not_hung(run_cli, files, tmp_path):
    rc, out, err = run_cli(["run", files / "ref.tif", files / "def.tif", "--search", "100000",
                         "-o", tmp_path / "r.npz", "--subset", "21", "--step", "12"])
    assert rc == 0, err
    assert "Traceback" not in err


@pytest.mark.parametrize("error", [KeyError("x"), RuntimeError("boom"), MemoryError()])
def test_an_unexpected_error_is_one_line(run_cli, files, monkeypatch, error):
    def broken(args):
        raise error

    monkeypatch.setitem(app.COMMANDS, "run", broken)
    monkeypatch.delenv("NAPARI_ALDIC_DEBUG", raising=False)
    rc, _, err = run_cli(["run", files / "ref.tif", files / "def.tif"])
    pattern = "out of memory" if isinstance(error, MemoryError) else \
        rf"unexpected {type(error).__name__}: .*NAPARI_ALDIC_DEBUG=1"
    _one_error_line(rc, err, pattern)


def test_debug_variable_shows_the_traceback(run_cli, files, monkeypatch):
    def broken(args):
        raise RuntimeError("boom")

    monkeypatch.setitem(app.COMMANDS, "run", broken)
    monkeypatch.setenv("NAPARI_ALDIC_DEBUG", "1")
    rc, _, err = run_cli(["run", files / "ref.tif", files / "def.tif"])
    assert rc == 2
    assert "Traceback" in err and "RuntimeError: boom" in err
    assert err.strip().splitlines()[-1].startswith("napari-aldic: error: unexpected RuntimeError")


def test_params_command_refuses_a_bad_value(run_cli, tmp_path):
    rc, _, err = run_cli(["params", tmp_path / "p.json", "--search", "0"])
    _one_error_line(rc, err, r"search=0 must be >= 1 pixel")
    assert not (tmp_path / "p.json").exists()


def test_good_inputs_still_work(run_cli, files, tmp_path):
    rc, _, err = run_cli(["export", files / "good.npz", "--to", "csv", "-o", tmp_path / "o.csv"])
    assert rc == 0, err
    cols = read_csv(tmp_path / "o.csv")["columns"]
    ok = cols["valid"]
    assert ok.sum() > 0.9 * ok.size and np.allclose(cols["u"][ok], 0.5, atol=0.02)
