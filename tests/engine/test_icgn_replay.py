"""Repeated IC-GN attempts from the same start are replayed, not solved
again (issue 22, speed; issue 25, the first run on the open-hole pair).

The repair waves restart a failed node from its best trusted neighbour's
warp, wave after wave, and again after the node's own search: until a
neighbour changes, that is the very same start, and IC-GN (deterministic)
gives the very same outcome. ``_State.run`` keeps each node's last
``REPLAYED`` starts and outcomes and hands the outcome back instead. The
results must be bit for bit those of solving every attempt, with fewer nodes
solved where nodes fail again and again (texture that matches nothing, off the specimen).
"""

import numpy as np
import pytest

from napari_aldic.engine import correlate, synthetic
from napari_aldic.engine.dic import icgn as icgn_mod, local as local_mod

REPLAYED = local_mod.REPLAYED
FIELD = synthetic.Affine.strain_rotation(exx=0.005, center=(128, 128), t=(1.3, -0.6))


@pytest.fixture(scope="module")
def noise_half():
    """Speckle on the right, on the left noise drawn anew in each image
    (texture that matches nothing: such nodes fail at every attempt)."""
    r, d = synthetic.speckle_pair((256, 256), FIELD, noise=0.5, seed=3)
    rng = np.random.default_rng(3)
    r, d = r.astype(np.float64), d.astype(np.float64)
    r[:, :128] = rng.normal(100.0, 20.0, (256, 128))
    d[:, :128] = rng.normal(100.0, 20.0, (256, 128))
    return r, d


def _run(monkeypatch, pair, replayed, method="local"):
    """The result with ``REPLAYED`` attempts remembered, and the number of
    node solves IC-GN ran."""
    monkeypatch.setattr(local_mod, "REPLAYED", replayed)
    solved = []
    real = icgn_mod.icgn_solve

    def counting(*args, **kw):
        solved.append(int(np.count_nonzero(args[7])))  # the active nodes
        return real(*args, **kw)
    monkeypatch.setattr(local_mod, "icgn_solve", counting)
    return correlate(*pair, subset=31, step=8, method=method), sum(solved)


FIELDS = ("u", "v", "dudx", "dudy", "dvdx", "dvdy", "zncc", "reason", "iterations")
#: AL-DIC's propagated u_std differs between two runs of the same pair by
#: ~1e-16 (so it did before the replay; the propagation solves on threads)
STD_RTOL = 1e-12


@pytest.mark.parametrize("method", ["local", "aldic"])
def test_replayed_attempts_give_the_results_of_solving_them(monkeypatch, noise_half, method):
    plain, n_plain = _run(monkeypatch, noise_half, 0, method)
    fast, n_fast = _run(monkeypatch, noise_half, REPLAYED, method)
    for name in FIELDS:
        a, b = getattr(plain, name), getattr(fast, name)
        assert np.array_equal(a, b, equal_nan=True), name
    for name in ("u_std", "v_std"):
        np.testing.assert_allclose(getattr(fast, name), getattr(plain, name), rtol=STD_RTOL,
                                   atol=0, equal_nan=True, err_msg=name)
    # the noise half's nodes fail at every attempt: their repeats (~90 of
    # ~1,340 node solves, the waves after the first) are not solved
    assert n_fast <= n_plain - 60, (n_fast, n_plain)


def test_a_changed_start_is_solved(monkeypatch, noise_half):
    """Only an identical start is replayed: a node started elsewhere is solved."""
    from napari_aldic.engine import DICParams
    from napari_aldic.engine.dic.correlate import _validity
    from napari_aldic.engine.dic.images import prepare_images
    from napari_aldic.engine.dic.local import _State
    from napari_aldic.engine.dic.mesh import make_grid
    from napari_aldic.engine.dic.subsets import split_subsets

    r, d = noise_half
    prm = DICParams(subset=31, step=8).fitted_to(r.shape)
    roi = np.ones(r.shape, bool)
    im = prepare_images(r.astype(np.float64), d.astype(np.float64), prm.interpolation)
    grid = make_grid(roi, prm.subset, prm.step)
    sub = split_subsets(roi, grid, prm.subset, prm.min_component)
    st = _State(im, roi, grid, sub, prm, _validity(im, roi, grid, sub, prm, {}))
    active = np.zeros(grid.n, bool)
    active[np.nonzero(st.usable)[0][:40]] = True
    p0 = np.zeros((grid.n, 6))
    p0[:, 0], p0[:, 3] = 1.3, -0.6
    first = st.run(active, p0)
    solved = []
    monkeypatch.setattr(local_mod, "icgn_solve",
                        lambda *a, **k: solved.append(np.count_nonzero(a[7])))
    again = st.run(active, p0)
    assert solved == []  # every start seen: nothing solved
    for a, b in zip(first, again):
        assert np.array_equal(a, b, equal_nan=True)
    moved = p0.copy()
    moved[active.nonzero()[0][:5], 0] += 0.25
    monkeypatch.undo()
    monkeypatch.setattr(local_mod, "icgn_solve", lambda *a, **k: (
        solved.append(np.count_nonzero(a[7])), icgn_mod.icgn_solve(*a, **k))[1])
    st.run(active, moved)
    assert solved == [5]
