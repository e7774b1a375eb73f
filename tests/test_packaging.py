"""A package people can find and install: the metadata a package index and the
napari hub show, and every third-party module the code imports declared as a
dependency (of the engine, or of the ``napari`` extra for the plugin)."""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src" / "napari_aldic"
#: import name -> distribution name, where they differ
DISTRIBUTION = {"PIL": "pillow", "skimage": "scikit-image", "imageio_ffmpeg": "imageio-ffmpeg",
                "yaml": "pyyaml"}


def _project() -> dict:
    return tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["project"]


def _names(requirements) -> set[str]:
    """Distribution names of requirement strings, normalised (PEP 503)."""
    return {re.sub(r"[-_.]+", "-", re.match(r"[A-Za-z0-9_.-]+", r).group(0)).lower()
            for r in requirements}


def _imports(folder: Path) -> dict[str, Path]:
    """Top-level third-party modules imported anywhere under ``folder`` -> a file."""
    found = {}
    for path in folder.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                tops = [a.name.split(".")[0] for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                tops = [node.module.split(".")[0]]
            else:
                continue
            for top in tops:
                if top not in sys.stdlib_module_names and top != "napari_aldic":
                    found.setdefault(top, path)
    return found


def test_every_imported_module_is_declared():
    project = _project()
    extras = project["optional-dependencies"]
    # the engine and the CLI: the dependencies, and the optional cluster and video
    # packages (imported inside the functions that need them)
    engine = _names(project["dependencies"]) | _names(extras["cluster"]) | \
        _names(extras["video"])
    plugin = engine | _names(extras["napari"])
    found = _imports(SRC)
    assert {"numpy", "scipy", "superqt"} <= set(found)  # the scan sees the imports
    for module, path in found.items():
        dist = DISTRIBUTION.get(module, module).lower().replace("_", "-")
        if path.relative_to(SRC).parts[0] in ("engine", "cli"):
            assert dist in engine, f"{module} (imported by {path}) is not declared"
        else:
            assert dist in plugin, f"{module} (imported by {path}) is not in [napari]"


def test_index_metadata():
    project = _project()
    assert set(project["urls"]) >= {"Homepage", "Documentation", "Bug Tracker", "User Support"}
    for url in project["urls"].values():
        assert url.startswith("https://")
    classifiers = project["classifiers"]
    for prefix in ("Development Status ::", "Intended Audience ::", "Operating System ::",
                   "Framework :: napari"):
        assert any(c.startswith(prefix) for c in classifiers), prefix
    extras = project["optional-dependencies"]
    assert "build" in _names(extras["testing"])  # CI builds the wheel and the sdist
    assert {"mkdocs", "mkdocstrings"} <= _names(extras["docs"])
