"""The command line starts compiling the kernels of a 2-D analysis before it
imports the commands (issue 25): which command lines do, with which groups."""

from __future__ import annotations

import pytest

from napari_aldic.cli import console


@pytest.fixture
def started(monkeypatch):
    calls = []
    import napari_aldic.engine as engine

    monkeypatch.setattr(engine, "precompile_kernels",
                        lambda groups, background=False: calls.append((groups, background)),
                        raising=False)
    return calls


@pytest.mark.parametrize("argv, groups", [
    (["run", "a.tif", "b.tif"], ("local",)),
    (["run", "a.tif", "b.tif", "--method", "aldic"], ("local", "aldic")),
    (["run", "a.tif", "b.tif", "--method=aldic", "--subset", "31"], ("local", "aldic")),
    (["run", "stack.tif", "--method", "local"], ("local",)),
    (["demo"], ("local", "synthetic")),
    (["demo", "--method", "aldic"], ("local", "aldic", "synthetic")),
    (["watch", "folder", "-o", "out"], ("local", "strain")),
])
def test_analysing_commands_compile_ahead(started, argv, groups):
    console.compile_ahead(argv)
    assert started == [(groups, True)]


@pytest.mark.parametrize("argv", [
    [], ["--help"], ["export", "r.npz", "--to", "csv"], ["params", "-o", "p.json"],
    ["run", "--help"], ["run", "a.tif", "b.tif", "-h"], ["run", "v.tif", "--volume"],
    ["probe", "r.npz"],
])
def test_other_command_lines_compile_nothing_ahead(started, argv):
    console.compile_ahead(argv)
    assert started == []


def test_a_failure_to_start_is_left_to_the_command(monkeypatch):
    import napari_aldic.engine as engine

    def broken(groups, background=False):
        raise OSError("no processes")

    monkeypatch.setattr(engine, "precompile_kernels", broken, raising=False)
    console.compile_ahead(["run", "a.tif", "b.tif"])  # no error: the command compiles
