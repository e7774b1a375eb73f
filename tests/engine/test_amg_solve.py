"""The AL-DIC global step on large meshes: AMG-preconditioned CG.

The threshold that switches from the SuperLU factor to AMG-CG is lowered so
that a small mesh (fast) takes the large-mesh path.
"""

import numpy as np
import pytest

from napari_aldic.engine import correlate, synthetic as S
from napari_aldic.engine.dic import linear_solvers
from napari_aldic.engine.dic.global_solve import GlobalSolver, Q4Mesh, solver_method


def _lattice(n: int, step: float = 16.0) -> Q4Mesh:
    iy, ix = np.mgrid[0:n, 0:n]
    idx = iy * n + ix
    e = np.column_stack([idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(),
                         idx[1:, 1:].ravel(), idx[1:, :-1].ravel()])
    return Q4Mesh(ix.ravel() * step, iy.ravel() * step, e.astype(np.int64))


def _admm_like_solves(solver, mesh, rng):
    N = mesh.n_nodes
    u = 0.4 * np.sin(mesh.x / 300.0) + 0.02 * rng.standard_normal(N)
    v = 0.2 * np.cos(mesh.y / 250.0) + 0.02 * rng.standard_normal(N)
    F = solver.gradients(u, v) + 1e-3 * rng.standard_normal((N, 4))
    W = 1e-4 * rng.standard_normal((N, 4))
    z = np.zeros(N)
    return [solver.solve(F, W, u + 0.01 * k, v, z, z) for k in range(3)]


@pytest.mark.parametrize("adaptive", [False, True])
def test_amg_cg_equals_the_direct_solve(monkeypatch, adaptive):
    monkeypatch.setattr(linear_solvers, "DIRECT_MAX_UNKNOWNS", 1000)
    mesh = _lattice(70)  # 4,900 unknowns per component: above the lowered threshold
    rng = np.random.default_rng(1)
    trusted = rng.random(mesh.n_nodes) > 0.03
    kappa = (rng.choice([0.0, 4.0, 8.0], mesh.n_nodes) ** 4 if adaptive else 8.0**4)
    kw = dict(beta=0.3, mu=1.0, weights=trusted, curvature=kappa)
    direct = GlobalSolver(mesh, method="direct", **kw)
    auto = GlobalSolver(mesh, **kw)
    assert direct.method == "direct" and auto.method == "amg"
    built = []
    import pyamg

    real = pyamg.rootnode_solver
    monkeypatch.setattr(pyamg, "rootnode_solver",
                        lambda *a, **k: built.append(1) or real(*a, **k))
    amg = GlobalSolver(mesh, method="amg", **kw)
    a = _admm_like_solves(direct, mesh, np.random.default_rng(2))
    b = _admm_like_solves(amg, mesh, np.random.default_rng(2))
    for (ua, va), (ub, vb) in zip(a, b):
        scale = np.abs(ua).max()
        assert np.abs(ua - ub).max() < 1e-5 * scale
        assert np.abs(va - vb).max() < 1e-5 * scale
    # one hierarchy for all solves with this matrix, and few CG iterations
    assert built == [1]
    its = amg.system.iterations
    assert len(its) == 6 and max(its) < 60, its
    assert amg.system.factor_nnz == 0 and direct.system.factor_nnz > mesh.n_nodes


def test_solver_choice_by_size_and_bad_names():
    assert solver_method(10, "auto") == "direct"
    assert solver_method(linear_solvers.DIRECT_MAX_UNKNOWNS + 1) == "amg"
    assert solver_method(10, "jacobi") == "jacobi"
    with pytest.raises(ValueError, match="solver method 'lu'"):
        solver_method(10, "lu")


def test_aldic_through_the_amg_path_matches_the_direct_path(monkeypatch):
    field = S.Sinusoid(0.4, 0.3, wavelength=200.0)
    ref, dfm = S.speckle_pair((160, 160), field, noise=4.0, seed=4, n_quad=3)
    direct = correlate(ref, dfm, subset=21, step=6, method="aldic")
    monkeypatch.setattr(linear_solvers, "DIRECT_MAX_UNKNOWNS", 100)
    amg = correlate(ref, dfm, subset=21, step=6, method="aldic")
    both = direct.valid & amg.valid
    assert both.mean() > 0.95
    assert np.abs(direct.u - amg.u)[both].max() < 1e-3
    assert np.abs(direct.v - amg.v)[both].max() < 1e-3
    # the uncertainty: propagated through the ADMM run with the direct solver;
    # on iteratively solved meshes the Local model of u_local, and said so
    assert direct.meta["u_std"].startswith("AL-DIC")
    assert amg.meta["u_std"].startswith("Local model")
    assert np.isfinite(amg.u_std[amg.valid]).all()
    local = correlate(ref, dfm, subset=21, step=6, method="local")
    same = both & local.valid
    # the fallback is the Local model (its u_local is within noise of Local's u) ...
    assert 0.95 < np.median(amg.u_std[same]) / np.median(local.u_std[same]) < 1.05
    # ... and well above the propagated AL-DIC figure (measured 1.78x here)
    assert np.median(amg.u_std[same]) > 1.4 * np.median(direct.u_std[same])



def test_factor_copied_ahead_is_the_same_and_let_go():
    """``SPDSolver.triangular_ahead`` copies the factor on a thread while the
    caller goes on; ``triangular()`` then returns that copy (the same solves,
    bit for bit, as one made on the spot) and lets it go, so a solver kept
    between frames does not hold a second copy of its factor."""
    import scipy.sparse as sp

    n = 400
    rng = np.random.default_rng(0)
    B = sp.random(n, n, density=0.01, random_state=1)
    A = (B @ B.T + sp.eye(n) * 4.0).tocsc()
    s = linear_solvers.SPDSolver(A, "direct", 0.0)
    s.triangular_ahead()
    s.triangular_ahead()  # once is enough
    ahead = s.triangular()
    assert s.triangular() is not ahead  # let go: the next one is a new copy
    b = rng.standard_normal((n, 6))
    np.testing.assert_array_equal(ahead.solve(b), s.triangular().solve(b))
    np.testing.assert_allclose(A @ ahead.solve(b), b, atol=1e-9)
    linear_solvers.SPDSolver(A, "jacobi", 1e-8).triangular_ahead()  # no factor: nothing


def test_triangular_solve_with_the_diagonal_anywhere_in_its_column():
    """``TriangularSolver`` moves each column's diagonal entry to where the
    compiled solve reads it (first in ``L``, last in ``U``): whatever order a
    factor stores its columns in, the solves agree bit for bit, and with
    SciPy's dense triangular solves to rounding."""
    import scipy.linalg as sla
    import scipy.sparse as sp

    rng = np.random.default_rng(3)
    n = 120
    L = sp.tril(sp.random(n, n, density=0.08, random_state=2), -1) + sp.diags(rng.uniform(1, 2, n))
    U = sp.triu(sp.random(n, n, density=0.08, random_state=5), 1) + sp.diags(rng.uniform(1, 2, n))

    def shuffled(M):  # the same matrix, each column's entries in a random order
        M = M.tocsc()
        order = np.concatenate([lo + rng.permutation(hi - lo)
                                for lo, hi in zip(M.indptr[:-1], M.indptr[1:])])
        return sp.csc_matrix((M.data[order], M.indices[order], M.indptr), shape=M.shape)

    class Factor:  # what TriangularSolver reads of a SuperLU object
        def __init__(self, L, U):
            self.L, self.U = L, U
            self.perm_r = self.perm_c = np.arange(n)

    b = rng.standard_normal((n, 5))
    x1 = linear_solvers.TriangularSolver(Factor(L, U)).solve(b)
    x2 = linear_solvers.TriangularSolver(Factor(shuffled(L), shuffled(U))).solve(b)
    np.testing.assert_array_equal(x1, x2)
    dense = sla.solve_triangular(U.toarray(), sla.solve_triangular(L.toarray(), b, lower=True))
    np.testing.assert_allclose(x1, dense, rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError, match="diagonal"):
        linear_solvers.TriangularSolver(Factor(sp.tril(L, -1).tocsc(), U))
