"""Conjugate gradients preconditioned by the thin-plate smoother's symbol on a
node lattice (a fast cosine transform), for the smoothing choice's longer
trial smoothers.

On a mesh whose nodes sit on one lattice of spacing ``step`` (no hanging
nodes), ``KᵀK`` (:func:`~.global_solve.curvature_operator`) is nearly
``(L_x + L_y)² / step⁴``, with ``L`` the Neumann second-difference matrix of
each axis: the element twists give exactly ``2 L_x L_y``, and the nodal
second differences ``L²`` up to their rows at the two ends of each lattice
line. The cosine transform (DCT-II) diagonalises ``L``, eigenvalues
``2 - 2 cos(π j / n)``, so ``(I + ℓ⁴ KᵀK)⁻¹`` is applied approximately in
``O(n log n)``. The approximation misses the edge rows, the ROI's outline and
the untrusted nodes' small data weight: CG corrects for them. Measured on
the 15k-node 1024² benchmark mesh, lengths of 1.4-1.9 node spacings need 13
iterations where Jacobi CG needs 120-210 (``docs/method.md`` section 7.4);
short lengths (below ~0.6 spacing) are dominated by the data weights, and
there the diagonal preconditions better.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft
import scipy.sparse as sp

from .global_solve import Q4Mesh
from .linear_solvers import cg_tolerances

__all__ = ["LatticePreconditioner", "lattice_of", "pcg_columns"]


def lattice_of(mesh: Q4Mesh, free: np.ndarray, step: float):
    """``(iy, ix, shape)``: the lattice cell of each free node, or None when the
    mesh is not one lattice of spacing ``step`` (hanging nodes, off-lattice or
    shared positions)."""
    if mesh.hanging.size or free.size != mesh.n_nodes or free.size == 0:
        return None
    fx = (mesh.x - mesh.x.min()) / step
    fy = (mesh.y - mesh.y.min()) / step
    ix, iy = np.rint(fx).astype(np.int64), np.rint(fy).astype(np.int64)
    if max(np.abs(fx - ix).max(), np.abs(fy - iy).max()) > 1e-6:
        return None
    shape = (int(iy.max()) + 1, int(ix.max()) + 1)
    if np.unique(iy * shape[1] + ix).size != ix.size:
        return None
    return iy, ix, shape


class LatticePreconditioner:
    """``r -> (I + (ℓ/step)⁴ (L_x + L_y)²)⁻¹ r`` on the lattice of the free
    nodes (each row of ``r`` (K, n) a field), zero-padded where the lattice has no node
    and up to a size the FFT handles fast: a symmetric positive definite
    approximation of ``(Wd + ℓ⁴ KᵀK)⁻¹``."""

    def __init__(self, lattice, length: float, step: float):
        iy, ix, shape = lattice
        self.nodes = shape
        # e.g. 124 -> 125 (5³): the transforms take 0.57 instead of 0.89 ms
        self.shape = tuple(sfft.next_fast_len(s, real=True) for s in shape)
        self.cell = iy * self.shape[1] + ix
        # nodes in row-major lattice order fill the grid by a slice, not a scatter
        self.full = (ix.size == shape[0] * shape[1]
                     and np.array_equal(iy * shape[1] + ix, np.arange(ix.size)))
        ly = 2.0 - 2.0 * np.cos(np.pi * np.arange(self.shape[0]) / self.shape[0])
        lx = 2.0 - 2.0 * np.cos(np.pi * np.arange(self.shape[1]) / self.shape[1])
        self.symbol = 1.0 / (1.0 + (length / step) ** 4 * (ly[:, None] + lx[None, :]) ** 2)

    def __call__(self, r: np.ndarray) -> np.ndarray:
        """The preconditioned residuals of ``r`` (K, n): one row per column."""
        k = r.shape[0]
        ny, nx = self.nodes
        grid = np.zeros((k, *self.shape))
        if self.full:
            grid[:, :ny, :nx] = r.reshape(k, ny, nx)
        else:
            grid.reshape(k, -1)[:, self.cell] = r
        # one worker: the caller already runs the trial smoothers side by side
        spec = sfft.dctn(grid, type=2, norm="ortho", axes=(1, 2), workers=1,
                         overwrite_x=True)
        spec *= self.symbol
        grid = sfft.idctn(spec, type=2, norm="ortho", axes=(1, 2), workers=1,
                          overwrite_x=True)
        out = (grid[:, :ny, :nx].reshape(k, -1) if self.full
               else grid.reshape(k, -1)[:, self.cell])
        return np.ascontiguousarray(out)


def pcg_columns(A: sp.csr_matrix, b: np.ndarray, x0: np.ndarray, precond, rtol: float,
                maxiter: int, atol: np.ndarray | None = None) -> np.ndarray | None:
    """``A⁻¹ b`` for the columns of ``b`` (n, K) by preconditioned CG from ``x0``:
    each column until its residual is ``rtol`` times its first one (so the
    tolerance applies to the correction ``x - x0``) or ``atol`` (K,), where
    given and larger, its iterates then frozen. None if a column needs more
    than ``maxiter`` iterations. ``precond`` maps residuals held as rows (K, n)
    to rows.

    The columns are held as rows, so that each is one contiguous vector:
    SciPy's product with one vector is twice as fast per column as with an
    (n, K) block (0.14 against 0.26 ms at 15k nodes). Sums are NumPy's einsum,
    not BLAS (threaded BLAS dot products of this length cost more in
    hand-overs than in arithmetic on a busy machine, see :mod:`~..kernels.cg`)."""
    x = np.array(np.transpose(x0), np.float64, order="C")
    r = np.ascontiguousarray(np.transpose(b), np.float64) - _times(A, x)
    atol = np.maximum(cg_tolerances(r.T, rtol)[0], 0.0 if atol is None else atol)
    active = np.sqrt(np.einsum("ij,ij->i", r, r)) > atol
    z = precond(r)
    p = z.copy()
    rz = np.einsum("ij,ij->i", r, z)
    for _ in range(maxiter):
        if not active.any():
            break
        Ap = _times(A, p)
        pAp = np.einsum("ij,ij->i", p, Ap)
        alpha = np.divide(rz, pAp, out=np.zeros_like(rz), where=active & (pAp > 0))[:, None]
        x += alpha * p
        r -= alpha * Ap
        active &= np.sqrt(np.einsum("ij,ij->i", r, r)) > atol
        z = precond(r)
        rz_new = np.einsum("ij,ij->i", r, z)
        beta = np.divide(rz_new, rz, out=np.zeros_like(rz), where=active & (rz > 0))[:, None]
        p = z + beta * p
        rz = rz_new
    return None if active.any() else np.ascontiguousarray(x.T)


def _times(A: sp.csr_matrix, rows: np.ndarray) -> np.ndarray:
    """``A`` times each row of ``rows`` (K, n), as rows."""
    out = np.empty_like(rows)
    for j in range(rows.shape[0]):
        out[j] = A @ rows[j]
    return out
