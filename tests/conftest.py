"""Fixtures shared by every test folder (engine/, cli/, plugin/).

The synthetic export data are computed once per test session (session-scoped
fixtures) and are read-only: a test that needs to change files copies them first.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
# the tests read the English text of widgets and messages: English whatever the developer's
# locale (a test that needs another language sets NAPARI_ALDIC_LANGUAGE or calls set_language)
os.environ["NAPARI_ALDIC_LANGUAGE"] = "en"
#: optional real speckle images, kept next to the repository (``../shared/data``);
#: ``NAPARI_ALDIC_SHARED_DATA`` points elsewhere. Tests that need them skip without them.
SHARED_DATA = Path(os.environ.get("NAPARI_ALDIC_SHARED_DATA", REPO.parent / "shared" / "data"))

# ------------------------------------------------------------------ export data
EXPORT_SHAPE = (128, 128)
EXPORT_N_FRAMES = 4
EXPORT_CENTER = (64.0, 64.0)


def _export_field(k: int):
    from napari_aldic.engine import synthetic as S

    return S.Affine.strain_rotation(exx=0.01 * k, eyy=-0.003 * k, center=EXPORT_CENTER,
                                    t=(0.3 * k, 0.1 * k))


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root (holds napari.yaml, sample_data/, src/)."""
    return REPO


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` (real speckle images); skips the test when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"optional real data not found: {SHARED_DATA} (a clone with ../shared/data, "
                    "or NAPARI_ALDIC_SHARED_DATA=<folder>, runs these tests)")
    return SHARED_DATA


@pytest.fixture(scope="session")
def export_field():
    """``export_field(k)``: the affine field that deforms frame k of :func:`export_stack`."""
    return _export_field


@pytest.fixture(scope="session")
def export_stack() -> np.ndarray:
    """(4, 128, 128) speckle stack; frame k is deformed by ``export_field(k)``."""
    from napari_aldic.engine import synthetic as S

    pat = S.make_pattern(EXPORT_SHAPE, seed=21, margin=32)
    return np.stack([S.render(pat, EXPORT_SHAPE, None if k == 0 else _export_field(k), n_quad=2,
                              seed=50 + k)
                     for k in range(EXPORT_N_FRAMES)])


@pytest.fixture(scope="session")
def _export_run(export_stack, tmp_path_factory):
    from napari_aldic.engine import track

    folder = tmp_path_factory.mktemp("aldic_export_run")
    seq = track(export_stack, subset=21, step=12, out_dir=folder)
    return seq, folder


@pytest.fixture(scope="session")
def export_sequence(_export_run):
    """A 4-frame SequenceResult of :func:`export_stack` (local IC-GN, 9 x 9 lattice)."""
    return _export_run[0]


@pytest.fixture(scope="session")
def export_run_folder(_export_run) -> Path:
    """The ``out_dir`` written by ``track`` for :func:`export_sequence` (do not modify)."""
    return _export_run[1]


@pytest.fixture(scope="session")
def aldic_result(export_stack):
    """An AL-DIC result on a quadtree mesh around a square hole in the ROI."""
    from napari_aldic.engine import correlate

    roi = np.ones(EXPORT_SHAPE, bool)
    roi[52:76, 52:76] = False
    res = correlate(export_stack[0], export_stack[2], roi=roi, subset=17, step=8,
                    method="aldic", refine="light")
    assert res.elements is not None and res.hanging is not None
    return res
