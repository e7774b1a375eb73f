"""The per-node matrices and uncertainty (``dic.covariance``, batched
NumPy) against the model written out node by node, and the noise factor
against ``np.interp``."""

import warnings

import numpy as np
import pytest

from napari_aldic.engine.dic.covariance import (
    MIN_SPECKLE_FRACTION,
    covariance_diag,
    gather_matrices,
    mean_noise_factor,
)


def _reference(a, ea, c, ec, var, m):
    """The model written out with np.linalg (one node at a time)."""
    n, s = a.shape[:2]
    k = s // 2
    out = np.full((n, 2), np.nan)
    for i in range(n):
        if not (m[i] > s and np.isfinite(var[i])):
            continue
        e_c, e_a = ec[i] * var[i], ea[i] * var[i]
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.diag(c[i]) / np.diag(e_c)
        r = r[np.isfinite(r) & (r > 0)]
        t = min((1 - MIN_SPECKLE_FRACTION) * r.min(), 1.0) if r.size else 1.0
        spk = c[i] - t * e_c
        if not np.isfinite(spk).all() or np.linalg.det(spk) <= 0:
            continue
        inv = np.linalg.inv(spk)
        cov = inv @ (a[i] - 0.5 * t * e_a) @ inv.T
        out[i] = 2 * var[i] * cov[0, 0], 2 * var[i] * cov[k, k]
    return out


def _packed(a, ea, c, ec, var, m, chunk=64):
    """``covariance_diag`` of four explicit matrices: their entries side by
    side in one array, gathered back by the tables, a few nodes at a time
    (the chunks' seams are crossed)."""
    n, s = a.shape[:2]
    flat = np.concatenate([v.reshape(n, s * s) for v in (a, ea, c, ec)], axis=1)
    col = np.arange(4 * s * s).reshape(4, s, s)
    return covariance_diag((flat,), np.zeros_like(col), col, np.ones(4), var, m, chunk=chunk)


def _nodes(rng, n, s):
    """Random well-conditioned node matrices: A = Σ J Jᵀ, C near A, noise
    parts on the diagonal blocks."""
    j = rng.normal(size=(n, s, 3 * s))
    a = j @ j.transpose(0, 2, 1)
    c = a + 0.1 * rng.normal(size=(n, s, s)) * np.sqrt(np.einsum("nii->n", a))[:, None, None] / s
    e = np.eye(s) * rng.uniform(0.5, 2.0, (n, 1, s))
    return a, e, c, 0.7 * e


@pytest.mark.parametrize("s", [2, 6, 12])
def test_covariance_matches_numpy(s):
    rng = np.random.default_rng(s)
    n = 300
    a, ea, c, ec = _nodes(rng, n, s)
    var = rng.uniform(0.0, 3.0, n)  # large var: the noise part is capped (t < 1)
    m = rng.uniform(0, 4 * s, n)  # some subsets too small: NaN
    var[::11] = np.nan
    c[5, 0, 0] = np.nan  # not finite: NaN
    c[7] = -c[7]  # det < 0 (even s: flip one row instead)
    c[7, 0] = -c[7, 0]
    ref = _reference(a, ea, c, ec, var, m)
    got = _packed(a, ea, c, ec, var, m)
    assert np.array_equal(np.isfinite(ref), np.isfinite(got))
    ok = np.isfinite(ref)
    assert ok.sum() > n // 3 and not ok[5].any() and not ok[::11].any()
    np.testing.assert_allclose(got[ok], ref[ok], rtol=1e-11)
    # and the plain-gradient form (C = A, E_C = E_A), the same arrays twice
    ref = _reference(a, ea, a, ea, var, m)
    got = _packed(a, ea, a, ea, var, m)
    np.testing.assert_allclose(got[np.isfinite(ref)], ref[np.isfinite(ref)], rtol=1e-11)
    assert np.array_equal(np.isfinite(ref), np.isfinite(got))



@pytest.mark.parametrize("s", [6, 12])
def test_covariance_needs_and_gets_pivoting(s):
    """``M`` with a zero leading entry in ``Mᵀ`` (elimination without row
    swaps divides by zero) is solved, and the sign of ``det M`` follows the
    row swaps: rows 0 and 1 swapped (det < 0) leave every such node out,
    rows 0, 1, 2 in a cycle (det > 0) keep every one."""
    rng = np.random.default_rng(40 + s)
    n = 60
    j = rng.normal(size=(n, s, 3 * s))
    a = j @ j.transpose(0, 2, 1)
    # diagonally dominant (det > 0, and still so with entry (1, 0) zeroed)
    c = a + np.eye(s) * 4 * np.abs(a).sum(axis=2)[:, :, None]
    c[:, 1, 0] = 0.0  # after the row swaps below this is M[0, 0]: Mᵀ's first pivot
    c[:20] = c[:20][:, [1, 0, *range(2, s)]]
    c[20:40] = c[20:40][:, [1, 2, 0, *range(3, s)]]
    c[40:] = c[40:][:, [1, 2, 0, *range(3, s)]]
    assert (c[:, 0, 0] == 0).all()
    det = np.linalg.det(c)
    assert (det[:20] < 0).all() and (det[20:] > 0).all()
    ea = np.zeros_like(a)  # no noise part: M = C exactly
    var = rng.uniform(0.1, 1.0, n)
    m = np.full(n, 10.0 * s)
    ref = _reference(a, ea, c, ea, var, m)
    got = _packed(a, ea, c, ea, var, m)
    assert np.isnan(got[:20]).all() and np.isnan(ref[:20]).all()
    assert np.isfinite(got[20:]).all()
    np.testing.assert_allclose(got[20:], ref[20:], rtol=1e-11)


def test_covariance_of_a_translation_is_pans_rule():
    """2 x 2, no gradient noise: 2 σ² H⁻¹ H H⁻¹ = 2 σ² H⁻¹."""
    h = np.array([[[400.0, 30.0], [30.0, 250.0]]])
    got = _packed(h, np.zeros_like(h), h, np.zeros_like(h), np.array([4.0]), np.array([441.0]))
    np.testing.assert_allclose(got[0], 8.0 * np.diag(np.linalg.inv(h[0])), rtol=1e-13)


@pytest.mark.filterwarnings("ignore:invalid value encountered in remainder")
def test_mean_noise_factor_is_np_interp_averaged_over_the_grid():
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 1.0, 65)
    rho = 1 - 0.4 * np.sin(np.pi * t) ** 2
    n = 500
    u, v = rng.normal(0, 3, n), rng.normal(0, 3, n)
    u[:40] = np.round(u[:40])  # whole pixels and table points exactly
    v[40:80] = np.round(v[40:80] * 64) / 64
    u[-1] = np.nan
    v[-2] = np.inf
    grad = rng.normal(0, 0.05, (n, 4))
    grad[-3] = 0.0
    u[-3] = -1e-17  # frac rounds to 1: the table's last entry
    half = rng.uniform(5, 15, n)
    off = np.linspace(-1.0, 1.0, 5)
    ref = np.zeros(n)
    for oa in off:
        for ob in off:
            uu = u + grad[:, 0] * oa * half + grad[:, 1] * ob * half
            vv = v + grad[:, 2] * oa * half + grad[:, 3] * ob * half
            ref += np.interp(np.mod(uu, 1.0), t, rho) * np.interp(np.mod(vv, 1.0), t, rho)
    ref /= off.size**2
    with warnings.catch_warnings():  # NaN and inf rows are handled, not warned of
        warnings.simplefilter("error")
        got = mean_noise_factor(u, v, grad, half, off, t, rho, chunk=64)  # chunks meet too
    assert np.isnan(got[-2:]).all()
    np.testing.assert_allclose(got[:-2], ref[:-2], rtol=1e-13)
    one = mean_noise_factor(u, v, grad, half, np.zeros(1), t, rho)
    np.testing.assert_allclose(one[:-2], (np.interp(np.mod(u, 1), t, rho)
                                          * np.interp(np.mod(v, 1), t, rho))[:-2], rtol=1e-14)


def test_gather_matrices_picks_moments_and_scales():
    rng = np.random.default_rng(2)
    m0, m1 = rng.normal(size=(7, 15)), rng.normal(size=(7, 6))
    src = np.array([[0, 1, -1], [1, 0, -1], [-1, -1, 0]])
    col = np.array([[0, 3, 0], [3, 14, 0], [0, 0, 5]])
    got = gather_matrices((m0, m1), src, col, 2.5)
    np.testing.assert_array_equal(gather_matrices((m0, m1), src, col, 2.5, slice(2, 5)),
                                  got[2:5])
    for i in range(7):
        want = np.array([[m0[i, 0], m1[i, 3], 0], [m1[i, 3], m0[i, 14], 0],
                         [0, 0, m0[i, 5]]]) * 2.5
        np.testing.assert_array_equal(got[i], want)


def test_scaled_tables_are_the_scaled_matrices():
    """The noise parts come from the pixel moments through a scale: the
    kernel's result is that of the matrices scaled beforehand."""
    rng = np.random.default_rng(4)
    n, s = 50, 4
    a, ea, c, ec = _nodes(rng, n, s)
    var, m = rng.uniform(0.5, 2.0, n), np.full(n, 100.0)
    flat = np.concatenate([v.reshape(n, s * s) for v in (a, ea, c, ec)], axis=1)
    col = np.arange(4 * s * s).reshape(4, s, s)
    scale = np.array([1.0, 0.3, 1.0, 0.7])
    got = covariance_diag((flat,), np.zeros_like(col), col, scale, var, m)
    np.testing.assert_allclose(got, _packed(a, 0.3 * ea, c, 0.7 * ec, var, m), rtol=1e-13)
