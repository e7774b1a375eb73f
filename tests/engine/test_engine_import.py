"""The engine must stay napari- and Qt-free, at run time (a fresh interpreter).

The static import rules (directions, public API, private names, cycles, sizes) are
in test_layout.py; this checks what importing the engine really loads.
"""

import subprocess
import sys

GUI_MODULES = ("napari", "qtpy", "PyQt5", "PyQt6", "PySide2", "PySide6", "magicgui", "vispy",
               "superqt")
SUBPACKAGES = ("core", "kernels", "dic", "io", "viz", "workflow", "synthetic")


def _loaded_after(statement: str) -> list[str]:
    """Top-level modules of interest present in sys.modules after ``statement``."""
    code = (
        f"import sys; {statement}; "
        f"bad = sorted({{m.split('.')[0] for m in sys.modules}} & set({GUI_MODULES!r})); "
        "bad += sorted(m for m in sys.modules if m.startswith(('napari_aldic._', "
        "'napari_aldic.cli'))); "
        "print(' '.join(bad) or 'OK')"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout.split()


def test_engine_import_pulls_no_gui_modules():
    assert _loaded_after("import napari_aldic.engine as e; import napari_aldic.engine.synthetic"
                         ) == ["OK"]


def test_every_engine_subpackage_imports_without_gui_plugin_or_cli():
    statement = "; ".join(f"import napari_aldic.engine.{p}" for p in SUBPACKAGES)
    assert _loaded_after(statement) == ["OK"]


def test_engine_names_import_on_first_use():
    """``import napari_aldic.engine`` loads neither SciPy nor Numba (the
    command line starts compiling before the rest imports, issue 25); a name's
    first use imports its module only."""
    code = ("import sys, napari_aldic.engine as e; "
            "before = sorted(m for m in ('scipy', 'numba', 'tifffile', 'zarr') "
            "if m in sys.modules); "
            "e.DICParams; "
            "print(before, 'napari_aldic.engine.dic.correlate' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["[]", "False"]
