"""Small synthetic results shared by the export tests (computed once per session)."""

from __future__ import annotations

import atexit
import functools
import shutil
import tempfile
from pathlib import Path

import numpy as np

from napari_aldic.engine import correlate, synthetic as S, track

SHAPE = (128, 128)
N_FRAMES = 4
CENTER = (64.0, 64.0)


def field(k: int):
    return S.Affine.strain_rotation(exx=0.01 * k, eyy=-0.003 * k, center=CENTER,
                                    t=(0.3 * k, 0.1 * k))


@functools.lru_cache(maxsize=None)
def stack() -> np.ndarray:
    pat = S.make_pattern(SHAPE, seed=21, margin=32)
    return np.stack([S.render(pat, SHAPE, None if k == 0 else field(k), n_quad=2, seed=50 + k)
                     for k in range(N_FRAMES)])


@functools.lru_cache(maxsize=None)
def _sequence_and_folder():
    folder = Path(tempfile.mkdtemp(prefix="aldic_export_run_"))
    atexit.register(shutil.rmtree, folder, True)
    seq = track(stack(), subset=21, step=12, out_dir=folder)
    return seq, folder


def sequence():
    """A 4-frame SequenceResult (local IC-GN, 9 x 9 lattice of nodes)."""
    return _sequence_and_folder()[0]


def run_folder() -> Path:
    """The ``out_dir`` written by ``track`` for :func:`sequence` (do not modify)."""
    return _sequence_and_folder()[1]


@functools.lru_cache(maxsize=None)
def aldic_result():
    """An AL-DIC result on a quadtree mesh around a square hole in the ROI."""
    st = stack()
    roi = np.ones(SHAPE, bool)
    roi[52:76, 52:76] = False
    res = correlate(st[0], st[2], roi=roi, subset=17, step=8, method="aldic", refine="light")
    assert res.elements is not None and res.hanging is not None
    return res
