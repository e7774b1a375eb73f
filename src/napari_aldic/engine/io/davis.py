"""DaVis / DefDAP-style text export."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.files import AtomicFiles, numbered_path, target_path
from .runs import collect_frames


# =================================================================== DaVis / DefDAP
def export_davis(data, path, *, frames=None) -> list[Path]:
    """Write DaVis-style 2D-vector text files, the HRDIC input DefDAP reads.

    One file per frame (``STEM_frame#####.txt`` for several frames): a first
    line ``#DaVis 8.4.0 2D-vector STEP ROWS COLS "position" "pixel" ...``
    then tab-separated ``x y u v`` rows in pixels over the full node lattice,
    rows of constant y with x increasing (the lattice order DefDAP expects);
    untrusted or missing nodes hold ``nan``. Only lattice results can be
    written (quadtree nodes off the lattice are skipped). Values stay in
    pixels: DefDAP applies its own scale.
    """
    path = target_path(path, (".txt",))
    fr_list, units, info = collect_frames(data, frames=frames, strain=False)
    targets = [path] if len(fr_list) == 1 else [numbered_path(path, fr.index) for fr in fr_list]
    written = []
    with AtomicFiles() as files:  # a frame series appears whole or not at all
        for fr, target in zip(fr_list, targets):
            _write_frame(files, fr.result, target)
            written.append(target)
    return written


def _write_frame(files, res, target) -> None:
    """One frame's DaVis table."""
    xs = np.asarray(res.grid_xs, float)
    ys = np.asarray(res.grid_ys, float)
    step = int(res.params.step)
    U = res.to_grid("u")
    V = res.to_grid("v")
    X, Y = np.meshgrid(xs, ys)
    table = np.column_stack([X.ravel(), Y.ravel(), U.ravel(), V.ravel()])
    head = (f'#DaVis 8.4.0 2D-vector {step} {ys.size} {xs.size} "position" "pixel" '
            '"position" "pixel" "displacement" "pixel" "displacement" "pixel"\n')
    with files.write(target) as tmp, open(tmp, "w", encoding="ascii", newline="\n") as fh:
        fh.write(head)
        np.savetxt(fh, table, fmt=["%.6f", "%.6f", "%.8g", "%.8g"], delimiter="\t")


