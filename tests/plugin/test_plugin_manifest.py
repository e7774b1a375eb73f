"""The plugin is discovered from the installed package and its manifest is valid."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import npe2

REPO = Path(__file__).resolve().parents[2]  # the repository root


def test_npe2_discovers_the_installed_plugin():
    pm = npe2.PluginManager.instance()
    pm.discover()
    manifest = pm.get_manifest("napari-aldic")
    contrib = manifest.contributions
    assert any(r.command == "napari-aldic.get_reader" for r in contrib.readers)
    assert {w.layer_types[0] for w in contrib.writers} >= {"image", "vectors"}
    assert [w.display_name for w in contrib.widgets] == ["Digital image correlation (AL-DIC)",
                                                         "Probes and stress-strain"]
    assert len(contrib.sample_data) >= 3
    measure = manifest.contributions.menus.get("napari/layers/measure", [])
    assert any(getattr(item, "command", None) == "napari-aldic.dic_widget" for item in measure)
    # the manifest the package ships is the repository's napari.yaml (symlinked)
    import napari_aldic

    packaged = Path(napari_aldic.__file__).parent / "napari.yaml"
    assert packaged.read_text() == (REPO / "napari.yaml").read_text()


def test_manifest_validates_with_imports():
    out = subprocess.run([sys.executable, "-m", "npe2", "validate", "napari-aldic", "--imports"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "valid" in (out.stdout + out.stderr).lower()
