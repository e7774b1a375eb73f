"""The engine must stay napari- and Qt-free."""

import subprocess
import sys


def test_engine_import_pulls_no_gui_modules():
    code = (
        "import sys; import napari_aldic.engine as e; import napari_aldic.engine.synthetic;"
        "bad = [m for m in ('napari', 'qtpy', 'PyQt5', 'PyQt6', 'PySide2', 'PySide6',"
        " 'magicgui', 'vispy') if m in sys.modules];"
        "print('BAD', bad) if bad else print('OK')"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "OK", out.stdout
