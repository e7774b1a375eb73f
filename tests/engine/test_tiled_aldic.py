"""AL-DIC of a pair larger than memory (issue 13, section 2): the ADMM local
step reads the images block by block and the global step solves the whole
mesh; the result is the in-memory AL-DIC's."""

from __future__ import annotations

import numpy as np
import pytest

from napari_aldic.engine import Cancelled, Reason, correlate, correlate_tiled, synthetic as S
from napari_aldic.engine.dic import global_solve, linear_solvers
from napari_aldic.engine.dic.mesh import make_grid
from napari_aldic.engine.io import LazyImage
from napari_aldic.engine.workflow.tiled import coarse_guess

# a field AL-DIC improves on (a wave of 1.3 subsets plus an affine part)
FIELD = S.Sum([S.Sinusoid(0.6, 0.4, 160.0),
               S.Affine(G=((0.004, 0.001), (-0.002, 0.003)), center=(256.0, 256.0),
                        t=(2.3, -1.6))])


@pytest.fixture(scope="module")
def pair():
    ref, dfm = S.speckle_pair((512, 512), FIELD, noise=3.0, n_quad=1, seed=5)
    roi = np.ones(ref.shape, bool)
    roi[200:330, 150:420] = False  # a hole across block borders
    return ref, dfm, roi


def _untiled(ref, dfm, roi, tiled):
    """The same analysis on the whole images: the tiled run's shared initial
    guess and parameters (the speckle scale measured by correlate itself)."""
    guess = coarse_guess(ref, dfm, roi, params=tiled.params.replace(method="local"),
                         tile_size=160)
    same = {"guess_of_this_pair": True}  # the guess is this pair's own coarse result
    return correlate(ref, dfm, roi=roi, params=tiled.params.replace(extra=same), guess=guess)


def _rmse(res, u, v, valid):
    tu, tv = FIELD.displacement(res.x, res.y)
    return float(np.sqrt(np.mean(((u - tu) ** 2 + (v - tv) ** 2)[valid])))


def test_tiled_aldic_equals_in_memory_aldic(pair):
    ref, dfm, roi = pair
    tiled = correlate_tiled(ref, dfm, roi=roi, step=8, method="aldic", tile_size=160,
                            workers=2, search=10)
    assert tiled.meta["tiled"]["blocks"] >= 9 and tiled.params.method == "aldic"
    whole = _untiled(ref, dfm, roi, tiled)
    assert len(tiled.meta["admm_history"]) == len(whole.meta["admm_history"]) >= 2
    assert np.array_equal(tiled.x, whole.x) and np.array_equal(tiled.y, whole.y)
    assert np.array_equal(tiled.reason, whole.reason)
    for name in ("u", "v", "dudx", "dudy", "dvdx", "dvdy", "zncc", "u_local", "v_local"):
        a, b = getattr(tiled, name), getattr(whole, name)
        assert np.nanmax(np.abs(a - b)) < 1e-6, name
    assert np.array_equal(tiled.elements, whole.elements)
    assert tiled.meta["regularisation"]["smooth_px"] == pytest.approx(
        whole.meta["regularisation"]["smooth_px"])
    ok = tiled.valid
    assert ok.mean() > 0.9
    # the global step did its job: half the Local error on this field
    assert _rmse(tiled, tiled.u, tiled.v, ok) < 0.6 * _rmse(tiled, tiled.u_local,
                                                            tiled.v_local, ok)


def test_tiled_aldic_on_the_iterative_solver_path(pair, monkeypatch):
    """Meshes past the direct solver's size (here forced small) are solved by
    AMG-preconditioned CG; u_std is then the Local model and says so."""
    ref, dfm, roi = pair
    monkeypatch.setattr(linear_solvers, "DIRECT_MAX_UNKNOWNS", 100)
    tiled = correlate_tiled(ref, dfm, roi=roi, step=16, method="aldic", tile_size=160,
                            search=10)
    whole = _untiled(ref, dfm, roi, tiled)
    assert "Local model" in tiled.meta["u_std"] and "Local model" in whole.meta["u_std"]
    assert np.array_equal(tiled.reason, whole.reason)
    assert np.max(np.abs(tiled.u - whole.u)) < 1e-6
    assert np.max(np.abs(tiled.v - whole.v)) < 1e-6
    # the Local model's image-noise level is each block's own estimate (measured:
    # within 6 %, median ratio 1.003)
    ratio = tiled.u_std[tiled.valid] / whole.u_std[tiled.valid]
    assert np.all(np.abs(ratio - 1) < 0.1) and abs(np.median(ratio) - 1) < 0.02


class _Spy:
    """A lazily read image that records the windows asked for by the AL-DIC
    stage (once ``stage`` says so; the Local blocks of so small an image
    reach across all of it with their search range)."""

    stage = [""]

    def __init__(self, arr):
        self.windows = []

        def read(rows: slice, cols: slice):
            if self.stage[0].startswith("AL-DIC"):
                self.windows.append((rows.stop - rows.start) * (cols.stop - cols.start))
            return arr[rows, cols]

        self.image = LazyImage(read, arr.shape, arr.dtype, "spy.tif", None)


def test_tiled_aldic_reads_windows_never_the_whole_image(pair, monkeypatch):
    ref, dfm, roi = pair
    monkeypatch.setattr(global_solve, "MESH_BAND_PIXELS", 20_000)  # mesh: bands of rows
    spies = [_Spy(a) for a in (ref, dfm, roi.astype(np.uint8))]

    def progress(frac, msg):
        _Spy.stage[0] = msg

    res = correlate_tiled(spies[0].image, spies[1].image, roi=spies[2].image, step=16,
                          method="aldic", tile_size=128, search=10, progress=progress)
    assert res.meta["admm_history"] and res.valid.mean() > 0.85
    for spy in spies:
        assert spy.windows and max(spy.windows) < 0.3 * ref.size  # 128² + margins
    # the local step re-read every block in every ADMM iteration
    passes = res.meta["timing"]["admm_passes"]
    assert passes == len(res.meta["admm_history"])
    assert len(spies[1].windows) >= passes * 16


def test_tiled_aldic_can_be_cancelled_between_blocks(pair):
    ref, dfm, roi = pair
    seen = []

    def progress(frac, msg):
        seen.append(msg)

    def cancel():  # once the ADMM local step has started
        return any("ADMM" in m for m in seen)

    with pytest.raises(Cancelled):
        correlate_tiled(ref, dfm, roi=roi, step=16, method="aldic", tile_size=160,
                        search=10, progress=progress, cancel=cancel)


def test_tiled_aldic_keeps_failed_nodes_flagged(pair):
    """Nodes of a blank region stay invalid through AL-DIC: the global field
    interpolates over them, but they are never promised valid."""
    ref, dfm, _ = pair
    ref, dfm = ref.copy(), dfm.copy()
    ref[:, :150] = 90
    dfm[:, :150] = 90
    res = correlate_tiled(ref, dfm, step=16, method="aldic", tile_size=160, search=10)
    left = res.x < 100  # subsets wholly in the blank band: the Local reason is kept
    assert left.any() and np.all(res.reason[left] == Reason.NO_TEXTURE)
    # subsets wholly in the texture: valid and right (beyond the node column whose
    # subsets straddle the band's static edge: see the closing note of this change)
    right = res.x - 15 >= 150
    tu, tv = FIELD.displacement(res.x, res.y)
    err = np.hypot(res.u - tu, res.v - tv)
    assert res.valid[right].mean() > 0.95
    assert np.sqrt(np.mean(err[right & res.valid] ** 2)) < 0.03
    assert np.max(err[(res.x >= 224) & res.valid]) < 0.05


def test_mesh_of_a_mask_read_in_bands_is_the_in_memory_one(pair, monkeypatch):
    _, _, roi = pair
    roi = roi.copy()
    roi[40:47, 300:305] = False  # a speck smaller than an element
    grid = make_grid(roi, 31, 8)
    whole = global_solve.uniform_mesh(grid, roi)
    monkeypatch.setattr(global_solve, "MESH_BAND_PIXELS", 5_000)  # a band per element row
    lazy = LazyImage(lambda r, c: roi[r, c].astype(np.uint8), roi.shape, np.uint8, "m", None)
    banded = global_solve.uniform_mesh(grid, lazy)
    assert np.array_equal(banded.elements, whole.elements)
    assert whole.n_elements < (grid.shape[0] - 1) * (grid.shape[1] - 1)
