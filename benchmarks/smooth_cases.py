"""What ``bench_accuracy.py`` and ``bench_noise.py`` share: their test fields
and one run of pyALDIC on a pair.

Both scripts are run as ``python benchmarks/SCRIPT.py``, so this folder is on
``sys.path`` and they import this module by its bare name.
"""

from __future__ import annotations

import json
import subprocess
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def fields():
    """The smooth cases: uniform strain plus a displacement wave (256 x 256 images).

    ``long_wave``: exx 0.5 %, eyy -0.2 %, u = 0.4 sin(2 pi x / 320),
    v = 0.3 sin(2 pi y / 320); ``short_wave``: exx 1 %, eyy -0.4 %,
    u = v = 0.5 sin(2 pi (x|y) / 128).
    """
    from napari_aldic.engine import synthetic as S

    return {
        "long_wave": S.Sum([S.Affine.strain_rotation(exx=0.005, eyy=-0.002, center=(128, 128)),
                            S.Sinusoid(0.4, 0.3, wavelength=320.0)]),
        "short_wave": S.Sum([S.Affine.strain_rotation(exx=0.01, eyy=-0.004, center=(128, 128)),
                             S.Sinusoid(0.5, 0.5, wavelength=128.0)]),
    }


def pyaldic_run(python: str, ref, dfm, subset: int, step: int, method: str):
    """pyALDIC (``pyaldic_runner.py`` in the interpreter ``python``) on the
    pair, one run without warm-up: its nodes and displacements ``(x, y, u, v)``."""
    import tifffile

    with tempfile.TemporaryDirectory() as tmp:
        r, d, out = Path(tmp) / "r.tif", Path(tmp) / "d.tif", Path(tmp) / "o.npz"
        tifffile.imwrite(r, ref, photometric="minisblack")
        tifffile.imwrite(d, dfm, photometric="minisblack")
        subprocess.run([python, str(HERE / "pyaldic_runner.py"), str(r), str(d), "--subset",
                        str(subset), "--step", str(step), "--method", method, "--repeat", "1",
                        "--no-warmup", "--out", str(out)],
                       check=True, capture_output=True, text=True)
        with np.load(out) as p:
            return p["x"], p["y"], p["u"], p["v"]


def write_rows(rows: list, path: Path | None) -> int:
    """Write the rows as JSON to ``path`` (if given); the script's exit status."""
    if path:
        path.write_text(json.dumps(rows, indent=1))
    return 0
