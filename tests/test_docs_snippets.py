"""The documentation matches the program: every ```python block of README.md and
docs/*.md runs, and the tables and lists that restate the code (parameters and
their defaults, reason codes, the API reference, the demo's outputs) agree with it.

Code blocks of one file run in order in one namespace, in a fresh temporary folder
that holds a link to the repository's ``sample_data`` (the docs use it as a clone
would). A block that cannot run here is marked in the document source by the line
``<!-- docs-test: skip: REASON -->`` just before it (keep these rare); the test
lists those blocks and their reasons.
"""

from __future__ import annotations

import ast
import contextlib
import io
import re
from dataclasses import fields
from pathlib import Path

import pytest

from napari_aldic.engine import DICParams, Reason

REPO = Path(__file__).resolve().parents[1]
DOCS = [REPO / "README.md"] + sorted((REPO / "docs").glob("*.md"))
SKIP = re.compile(r"<!--\s*docs-test:\s*skip:\s*(.+?)\s*-->")
FENCE = re.compile(r"^```python[^\n]*\n(.*?)^```", re.S | re.M)


def python_blocks(path: Path) -> list[tuple[int, str, str | None]]:
    """``(line, code, skip reason or None)`` of every ```python block of ``path``."""
    text = path.read_text(encoding="utf-8")
    out = []
    for m in FENCE.finditer(text):
        line = text.count("\n", 0, m.start()) + 1
        before = text[:m.start()].rstrip().splitlines()[-1:] or [""]
        skip = SKIP.search(before[0])
        out.append((line, m.group(1), skip.group(1) if skip else None))
    return out


WITH_CODE = [p for p in DOCS if python_blocks(p)]


@pytest.mark.slow  # the blocks correlate real and synthetic images: 2-10 s per file
@pytest.mark.parametrize("path", WITH_CODE, ids=[p.name for p in WITH_CODE])
def test_python_blocks_run(path, tmp_path, monkeypatch):
    (tmp_path / "sample_data").symlink_to(REPO / "sample_data", target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__docs__"}
    blocks = python_blocks(path)
    if all(skip for _, _, skip in blocks):
        pytest.skip(f"{path.name}: every block is marked to skip: "
                    + "; ".join(skip for _, _, skip in blocks))
    for line, code, skip in blocks:
        if skip:
            continue
        with contextlib.redirect_stdout(io.StringIO()):
            try:
                exec(compile(code, f"{path.name}, block at line {line}", "exec"), namespace)
            except Exception as exc:
                pytest.fail(f"{path.name}, block at line {line}: {type(exc).__name__}: {exc}")


def test_skipped_blocks_are_rare_and_say_why():
    skipped = [(p.name, line, why) for p in DOCS for line, _, why in python_blocks(p) if why]
    total = sum(len(python_blocks(p)) for p in DOCS)
    assert len(skipped) <= max(1, total // 4), skipped
    assert all(len(why) > 10 for _, _, why in skipped), skipped


# ------------------------------------------------------------------ tables and lists
def _table_rows(text: str, header: str) -> list[list[str]]:
    """The rows of the markdown table whose header row starts with ``header``."""
    lines = text.splitlines()
    start = next(i for i, t in enumerate(lines) if t.startswith(header))
    rows = []
    for t in lines[start + 2:]:
        if not t.startswith("|"):
            break
        rows.append([c.strip() for c in t.strip().strip("|").split("|")])
    return rows


def _value(cell: str):
    cell = cell.strip("`")
    return None if cell == "None" else ast.literal_eval(cell)


def test_the_parameter_table_lists_every_field_with_its_default():
    text = (REPO / "docs" / "conventions.md").read_text(encoding="utf-8")
    rows = _table_rows(text, "| field | default |")
    documented = {r[0].strip("`"): _value(r[1]) for r in rows}
    defaults = DICParams()
    names = [f.name for f in fields(DICParams) if f.name != "extra"]
    assert set(documented) == set(names)
    for name in names:
        assert documented[name] == getattr(defaults, name), name


def test_the_reason_table_lists_every_code():
    text = (REPO / "docs" / "conventions.md").read_text(encoding="utf-8")
    rows = _table_rows(text, "| code | name |")
    assert {(int(r[0]), r[1].strip("`")) for r in rows} == {(int(r), r.name) for r in Reason}


def test_the_api_reference_lists_the_public_api():
    import inspect

    from napari_aldic import engine

    text = (REPO / "docs" / "api.md").read_text(encoding="utf-8")
    block = text.split("::: napari_aldic.engine\n", 1)[1].split(":::", 1)[0]
    listed = re.findall(r"^\s+- (\w+)\s*$", block, re.M)
    modules = [n for n in engine.__all__ if inspect.ismodule(getattr(engine, n))]
    assert sorted(listed) == sorted(n for n in engine.__all__ if n not in modules)
    for module in modules:  # each public subpackage has its own section
        assert f"::: napari_aldic.engine.{module}\n" in text, module


def test_readme_names_the_files_the_demo_writes(tmp_path):
    from napari_aldic.cli import main

    text = (REPO / "README.md").read_text(encoding="utf-8")
    sentence = re.search(r"It writes (.+?) into `\./aldic_demo/`", text, re.S).group(1)
    named = set(re.findall(r"`([\w.]+\.\w+)`", sentence))
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["demo", "--out", str(tmp_path), "--size", "96", "--step", "16"]) == 0
    assert named == {p.name for p in tmp_path.iterdir()}


def test_readme_links_and_images_exist():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    raw = "https://raw.githubusercontent.com/napari-aldic/napari-aldic/main/"
    images = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert images, "the README shows no screenshot"
    for url in images:
        assert url.startswith(raw), url  # absolute: the napari hub shows the README
        assert (REPO / url[len(raw):]).is_file(), url
    site = "https://napari-aldic.github.io/napari-aldic/"
    source = "https://github.com/napari-aldic/napari-aldic/blob/main/"
    for target in re.findall(r"(?<!!)\[[^\]]*\]\(([^)#]+)(?:#[^)]*)?\)", text):
        # absolute: relative links break on PyPI and the napari hub (issue 25)
        assert target.startswith("http"), target
        if target.startswith(site):  # a page of the documentation site
            page = target[len(site):].strip("/") or "index"
            assert (REPO / "docs" / f"{page}.md").is_file(), target
        elif target.startswith(source):
            assert (REPO / target[len(source):]).exists(), target
