"""The affine IC-GN's reference sums (``kernels.icgn.affine_reference_sums``,
three passes of 12 sums) against their definition: the instrumental-variable
matrix ``H = sum J e^T`` with ``J = (gx, gx dx, gx dy, gy, gy dx, gy dy)`` and
``e`` the same with the exact gradients, ``sum J`` and ``sum J (f - fm)``. A
swapped block (``gx ey`` for ``gy ex``) or moment leaves IC-GN converging to
the same point, only more slowly: the accuracy tests would not see it."""

import numba as nb
import numpy as np

from napari_aldic.engine.kernels.icgn import affine_reference_sums


@nb.njit
def _call(dxs, dys, gx, gy, ex, ey, fs, m, fm, H):  # the helper has no Python wrapper
    return affine_reference_sums(dxs, dys, gx, gy, ex, ey, fs, m, fm, H)


def test_reference_sums_are_their_definition():
    rng = np.random.default_rng(7)
    h = 7
    dy, dx = np.mgrid[-h:h + 1, -h:h + 1].astype(np.float64)
    dxs, dys = dx.ravel(), dy.ravel()
    m = dxs.size - 5  # a cut subset: the last pixels are not read
    gx, gy, ex, ey = (rng.normal(0, 20, dxs.size) for _ in range(4))
    fs = rng.uniform(0, 255, dxs.size)
    fm = fs[:m].mean()
    H = np.empty((6, 6))
    out = np.array(_call(dxs, dys, gx, gy, ex, ey, fs, m, fm, H))
    s = slice(0, m)
    J = np.stack([gx, gx * dxs, gx * dys, gy, gy * dxs, gy * dys])[:, s]
    E = np.stack([ex, ex * dxs, ex * dys, ey, ey * dxs, ey * dys])[:, s]
    scale = np.abs(J @ E.T).max()
    np.testing.assert_allclose(H, J @ E.T, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(out[:6], J.sum(axis=1), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(out[6:], J @ (fs[s] - fm), rtol=1e-12, atol=1e-7)
    assert not np.allclose(H, H.T)  # J differs from e: both off-diagonal blocks checked
