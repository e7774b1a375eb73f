"""The linear solvers of the smoothing choice: the multi-column Jacobi CG kernel,
the trial smoothers solved by CG on their correction (Jacobi, or on a lattice
mesh the cosine-transform preconditioner), and the factor they fall back to
when CG stalls."""

from concurrent.futures import Future

import numpy as np
import pytest
import scipy.sparse as sp

from napari_aldic.engine.dic import trial_smoothers as TS
from napari_aldic.engine.dic.global_solve import UNTRUSTED_WEIGHT, curvature_operator, uniform_mesh
from napari_aldic.engine.dic.lattice_pcg import LatticePreconditioner, lattice_of, pcg_columns
from napari_aldic.engine.dic.linear_solvers import cg_tolerances
from napari_aldic.engine.dic.mesh import make_grid
from napari_aldic.engine.dic.regularise import SMOOTH_CANDIDATES
from napari_aldic.engine.kernels.cg import jacobi_cg


def _mesh(shape=(240, 280), subset=31, step=8):
    roi = np.ones(shape, bool)
    return uniform_mesh(make_grid(roi, subset, step), roi)


def _fields(mesh, seed=0):
    """A smooth field with detail and noise, and a second, smaller one."""
    rng = np.random.default_rng(seed)
    n = mesh.n_nodes
    u = 3.0 + 2e-3 * mesh.x + 0.4 * np.sin(mesh.y / 19.0) + 0.01 * rng.standard_normal(n)
    v = -1.0 + 1e-3 * mesh.y - 0.2 * np.cos(mesh.x / 27.0) + 0.01 * rng.standard_normal(n)
    return np.column_stack([u, v])


def test_cg_solves_each_column_as_alone_bit_for_bit():
    """All columns in one pass over A give each column exactly what solving it
    alone gives (and its own iteration count); a zero column stays zero."""
    mesh = _mesh((160, 200), 15, 8)
    K = curvature_operator(mesh).tocsr()
    A = (sp.eye(mesh.n_nodes) + 3.0 * (K.T @ K)).tocsr()
    rng = np.random.default_rng(1)
    b = rng.standard_normal((mesh.n_nodes, 5))
    b[:, 2] = 0.0
    b[:, 4] *= 1e-3  # converges in a different number of iterations
    dinv = 1.0 / A.diagonal()
    atol, zero = cg_tolerances(b, 1e-8)
    assert zero.tolist() == [False, False, True, False, False]
    x = np.zeros_like(b)
    its = np.zeros(5, np.int64)
    jacobi_cg(A.indptr, A.indices, A.data, dinv, b, x, atol, 500, its)
    for c in range(5):
        xc = np.zeros((b.shape[0], 1))
        ic = np.zeros(1, np.int64)
        jacobi_cg(A.indptr, A.indices, A.data, dinv, np.ascontiguousarray(b[:, c:c + 1]), xc,
                  atol[c:c + 1], 500, ic)
        assert np.array_equal(x[:, c], xc[:, 0]) and its[c] == ic[0]
    assert its[2] == 0 and not x[:, 2].any()
    assert 0 < its.max() < 500
    res = np.sqrt(np.sum((b - A @ x) ** 2, axis=0))
    assert np.all(res[~zero] < atol[~zero])


class _Count:
    """Counts the factors SPDSolver builds in the smoothing choice."""

    def __init__(self, monkeypatch):
        self.n = 0
        real = TS.SPDSolver

        def spy(A, method, rtol):
            s = real(A, method, rtol)
            self.n += s.method == "direct"
            return s
        monkeypatch.setattr(TS, "SPDSolver", spy)


@pytest.fixture(autouse=True)
def _small_meshes_too(monkeypatch):
    """These meshes are below CG_MIN_NODES (where factors are cheaper): CG anyway."""
    monkeypatch.setattr(TS, "CG_MIN_NODES", 0)


def _residuals(mesh, fields, keep, late=True, workers=TS.SMOOTHING_THREADS):
    lengths = [float(c) * 31 for c in SMOOTH_CANDIDATES]
    fut = None
    if late:  # the bias columns arrive late, as in choose_smoothing
        fut = Future()
        fut.set_result(0.01 * np.sin(fields[:, ::-1] / 7.0))
    return TS.trial_residuals(mesh, fields, keep, lengths, 8.0, fut, workers)


@pytest.mark.parametrize("workers", [1, 5])
def test_trial_smoothers_do_not_depend_on_the_workers(workers):
    """More (or fewer) threads solving lengths side by side give the same bits:
    each job computes the same whatever runs beside it, and a job waits only
    on jobs listed before it (no deadlock with one worker)."""
    mesh = _mesh()
    fields = _fields(mesh, 6)
    keep = mesh.y > mesh.y.min()
    np.testing.assert_array_equal(_residuals(mesh, fields, keep, workers=workers),
                                  _residuals(mesh, fields, keep))


def _factored(monkeypatch, mesh, fields, keep):
    with monkeypatch.context() as m:
        m.setattr(TS, "CG_MAX_LENGTH", 0.0)  # every trial length by a factor
        m.setattr(TS, "LATTICE_MIN_LENGTH", np.inf)
        return _residuals(mesh, fields, keep)


@pytest.mark.parametrize("lattice", [False, True])
def test_trial_smoothers_by_cg_agree_with_factors(monkeypatch, lattice):
    """The short lengths are solved by Jacobi CG on the correction S f - f and,
    on a lattice mesh, the long ones by the cosine-transform preconditioned CG:
    no factor at all there (two, for the long lengths, without the lattice
    path). Both agree with the factored smoother far below the noise the risk
    weighs (rigid offset of 3 px in the fields: the tolerance is the correction's)."""
    mesh = _mesh()
    fields = _fields(mesh)
    keep = mesh.y > mesh.y.min()  # an untrusted first row, as in the 1024² benchmark
    ref = _factored(monkeypatch, mesh, fields, keep)
    if not lattice:
        monkeypatch.setattr(TS, "LATTICE_MIN_LENGTH", np.inf)
    count = _Count(monkeypatch)
    got = _residuals(mesh, fields, keep)
    lengths = np.array(SMOOTH_CANDIDATES) * 31
    assert count.n == (0 if lattice else int(np.sum(lengths > TS.CG_MAX_LENGTH * 8)))
    assert np.isfinite(got[keep]).all() and np.isnan(got[~keep]).all()
    # per length and column (u, v, then the late ones): 1e-5 of CG's first
    # residual (CG_RTOL) leaves up to ~7e-4 of the correction here; the risk
    # weighs its square
    err = np.abs(got[keep] - ref[keep]).max(axis=0)[1:]
    scale = np.abs(ref[keep]).max(axis=0)[1:]
    assert np.all(scale > 5e-6)
    assert np.all(err < 2e-3 * scale)


@pytest.mark.parametrize("case, cap, lattice_cap, factors", [
    ("block", TS.CG_MAX_ITER, TS.LATTICE_MAX_ITER, 6), ("row", 40, None, 4), ("row", 40, 3, 4)])
def test_trial_smoothers_fall_back_to_factors_where_cg_stalls(monkeypatch, case, cap,
                                                              lattice_cap, factors):
    """A 40 % untrusted block makes CG stall at the first (shortest) length:
    every length is then factorised (6). With one untrusted row and a cap of
    40 iterations (no lattice path) Jacobi CG converges on the two shortest
    lengths and stalls on the next two, whose late columns must still be
    solved: 2 long + 2 stalled factors. With the lattice path capped at 3
    iterations, its three lengths stall and the fourth by Jacobi CG: 4 again.
    Either way the result is the factored one."""
    mesh = _mesh((320, 320))
    fields = _fields(mesh, 2)
    keep = mesh.x < 200 if case == "block" else mesh.y > mesh.y.min()
    ref = _factored(monkeypatch, mesh, fields, keep)
    monkeypatch.setattr(TS, "CG_MAX_ITER", cap)
    if lattice_cap is None:
        monkeypatch.setattr(TS, "LATTICE_MIN_LENGTH", np.inf)
    else:
        monkeypatch.setattr(TS, "LATTICE_MAX_ITER", lattice_cap)
    count = _Count(monkeypatch)
    got = _residuals(mesh, fields, keep)
    assert count.n == factors
    assert got.shape == ref.shape and np.isfinite(got[keep]).all()
    err = np.abs(got[keep] - ref[keep]).max(axis=0)[1:]
    assert np.all(err < 2e-4 * np.abs(ref[keep]).max(axis=0)[1:])


def test_cg_first_solver_factors_after_a_stall(monkeypatch):
    """_CGFirst: CG from the start it is given, warm-started after, and a factor
    for good once CG stalls (the bias smoother of the 40 % untrusted block)."""
    mesh = _mesh((320, 320))
    keep = mesh.x < 200
    KtK = (curvature_operator(mesh).T @ curvature_operator(mesh)).tocsr()
    for wd, stalls in ((np.ones(mesh.n_nodes), False),
                       (np.where(keep, 1.0, UNTRUSTED_WEIGHT), True)):
        count = _Count(monkeypatch)
        A = (sp.diags(wd) + 7.5**4 * KtK).tocsc()
        f = _fields(mesh, 4)
        # all data: started from the field; the block: filled off the data
        s = TS.CGFirst(A, f if not stalls else np.where(keep[:, None], f, f.mean(axis=0)))
        b = sp.diags(wd) @ f
        x1 = s.solve(b)
        x2 = s.solve(b * 1.01)
        assert count.n == int(stalls)
        exact = sp.linalg.spsolve(A, b)
        scale = np.abs(exact - f)[keep].max()
        assert np.abs(x1 - exact)[keep].max() < 2e-4 * scale
        assert np.abs(x2 - 1.01 * exact)[keep].max() < 2e-4 * scale


def test_cg_first_later_solves_keep_the_first_absolute_tolerance(monkeypatch):
    """A warm-started later solve (the bias's fixed-point steps: the right-hand
    side changes little) stops at the first solve's absolute tolerance instead
    of CG_RTOL of its own small first residual: fewer iterations, and the same
    accuracy as the first solve (a relative-only stop needed nearly as many
    iterations as the first solve every time: 13, 12, 12 here)."""
    mesh = _mesh((320, 320))
    KtK = (curvature_operator(mesh).T @ curvature_operator(mesh)).tocsr()
    A = (sp.eye(mesh.n_nodes) + 12.0**4 * KtK).tocsc()
    f = _fields(mesh, 4)
    its = []
    real = TS.jacobi_cg

    def spy(*args):
        real(*args)
        its.append(int(args[-1].max()))
    monkeypatch.setattr(TS, "jacobi_cg", spy)
    s = TS.CGFirst(A, f)
    x1 = s.solve(f)
    x2 = s.solve(f * (1 + 1e-3))
    exact = sp.linalg.spsolve(A, f)
    scale = np.abs(exact - f).max()
    assert np.abs(x1 - exact).max() < 2e-4 * scale
    assert np.abs(x2 - (1 + 1e-3) * exact).max() < 2e-4 * scale
    # a solver whose first solve is that one (a relative stop, from the same
    # start) needs more iterations for the same answer: 9 against 12 here (a
    # relative stop in the warm-started solver also took 12)
    TS.CGFirst(A, x1).solve(f * (1 + 1e-3))
    assert its[1] <= 0.8 * its[2], its


def test_lattice_of_accepts_one_lattice_only():
    """The lattice path needs every node on one lattice of the node spacing:
    a uniform mesh (with or without an ROI hole) is one; a refined quadtree
    mesh (hanging nodes) or a spacing that does not match is not."""
    from napari_aldic.engine.dic.quadtree import Refinement, build_quadtree

    mesh = _mesh((160, 200))
    free = mesh.prolongation()[1]
    iy, ix, shape = lattice_of(mesh, free, 8.0)
    assert shape == (int(iy.max()) + 1, int(ix.max()) + 1)
    assert np.unique(iy * shape[1] + ix).size == mesh.n_nodes
    assert lattice_of(mesh, free, 5.0) is None
    roi = np.ones((200, 200), bool)
    roi[80:120, 80:120] = False
    holed = uniform_mesh(make_grid(roi, 15, 8), roi)
    assert lattice_of(holed, holed.prolongation()[1], 8.0) is not None
    grid = make_grid(roi, 15, 8)
    qm = build_quadtree(grid, roi, Refinement(mask_boundary=True, levels=2), 7).mesh
    assert qm.hanging.size and lattice_of(qm, qm.prolongation()[1], 8.0) is None


@pytest.mark.parametrize("length", [7.75, 15.5, 31.0])
def test_lattice_pcg_solves_the_smoother_where_the_symbol_is_only_approximate(length):
    """The preconditioner ignores the edge rows, an ROI hole and the untrusted
    nodes' small weight: CG still reaches the factored solution (relative
    tolerance 1e-10 of the correction), in far fewer iterations than Jacobi CG
    needs (counted by the preconditioner's calls)."""
    roi = np.ones((300, 340), bool)
    roi[100:160, 120:200] = False
    mesh = uniform_mesh(make_grid(roi, 31, 8), roi)
    free = mesh.prolongation()[1]
    lat = lattice_of(mesh, free, 8.0)
    wd = np.where((mesh.x > 250) & (mesh.y < 60), UNTRUSTED_WEIGHT, 1.0)
    A = (sp.diags(wd) + length**4 * curvature_operator(mesh)).tocsr()
    f = _fields(mesh, 5)
    b = wd[:, None] * f
    exact = sp.linalg.spsolve(A.tocsc(), b)
    calls = [0]
    M = LatticePreconditioner(lat, length, 8.0)

    def counted(r):
        calls[0] += 1
        return M(r)
    x = pcg_columns(A, b, f, counted, 1e-10, 200)
    assert x is not None
    assert np.abs(x - exact).max() < 1e-7 * np.abs(exact - f).max()
    assert calls[0] < 60
    jacobi = [0]
    dinv = 1.0 / A.diagonal()

    def diagonal(r):
        jacobi[0] += 1
        return r * dinv  # residuals as rows (K, n)
    assert pcg_columns(A, b, f, diagonal, 1e-10, 5000) is not None
    assert jacobi[0] > 2.5 * calls[0]
    assert pcg_columns(A, b, f, M, 1e-10, 3) is None  # a cap it cannot meet: None


def test_mesh_operators_built_once_when_threads_ask_at_once(monkeypatch):
    """The smoothing choice's two threads ask for the same mesh operators at
    the same moment: the second waits for the first one's build instead of
    building them again (each did, 2 x 30 ms at 15k nodes); a build that
    fails is not kept, so the next call builds again."""
    import threading
    import time

    from napari_aldic.engine.dic import global_solve as GS

    mesh = _mesh()
    builds = []
    real = GS._second_differences

    def slow(m):
        builds.append(threading.get_ident())
        time.sleep(0.2)
        return real(m)
    monkeypatch.setattr(GS, "_second_differences", slow)
    got = []
    threads = [threading.Thread(target=lambda: got.append(GS.second_difference_operators(mesh)))
               for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(builds) == 1 and len(got) == 3
    assert all(g is got[0] for g in got)

    calls = []

    def failing(m):
        calls.append(1)
        raise RuntimeError("no")
    fresh = GS.Q4Mesh(mesh.x, mesh.y, mesh.elements)
    monkeypatch.setattr(GS, "_second_differences", failing)
    for _ in range(2):
        with pytest.raises(RuntimeError):
            GS.second_difference_operators(fresh)
    assert len(calls) == 2


def test_mesh_with_its_operators_pickles():
    """A mesh whose operators were built keeps them as plain values (a
    cluster's workers receive meshes; an operator still being built is the
    only Future in its store)."""
    import pickle

    mesh = _mesh()
    T, _ = mesh.prolongation()
    curvature_operator(mesh)
    back = pickle.loads(pickle.dumps(mesh))
    assert (back.prolongation()[0] != T).nnz == 0
