"""Window sums of noise probes: ``Σ_window J n X^p Y^q`` at every node, for a
batch of noise images ``n`` at once (AL-DIC's ``u_std`` propagation,
``dic.uncertainty_aldic.noise_projector``).

The probes are independent ±1 images (Rademacher), given as packed bits
(NumPy's ``unpackbits`` order: pixel ``i`` of the row-major image is bit
``7 - i % 8`` of byte ``i // 8``), or as float images. The two steepest-descent
images ``J = (jx, jy)`` are read once for all probes of a call: per pixel the
products with every probe are added to running row sums (the probes are the
innermost, contiguous axis, so the loop vectorises), snapshotted at the
window edges of the distinct node columns; the window's row sums times
``Y^q`` go into one accumulator per (distinct column, moment, probe); a node's
sums are the accumulator after its window's last row less the one before its
first row.

The general streaming kernel (``moments.moments_kernel``) does the same for any
products, one probe's two products at a time, with its accumulators restarting
every few rows for the cancellation of high orders; here the orders are at most
2, the coordinates image-centred and the sums float64, which leaves the
differences ~2e-14 relative (``tests/engine/test_noise_sums.py``), and reading
the gradients once for many probes makes the sums ~2.5x cheaper (16 probes at
1024²: 0.30-0.38 against 0.12-0.14 CPU-s). Moments about each node follow from
these by ``moments.centre_moments``.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import CACHED, FASTMATH, INLINE

__all__ = ["noise_window_sums", "MAX_NOISE_ORDER"]

#: highest moment order ``p + q`` of :func:`noise_window_sums` (the quadratic
#: shape function's)
MAX_NOISE_ORDER = 2


@nb.njit(**INLINE, fastmath=FASTMATH)
def _noise_row(bits, noise, r, w, z):
    """Row ``r`` of every probe into ``z`` (w, K): ±1 from the packed ``bits``
    (K, bytes) when it has rows, else ``noise`` (K, H, W)."""
    if bits.shape[0] > 0:
        base = r * w
        for x in range(w):
            i = base + x
            sh = 7 - (i & 7)
            byte = i >> 3
            for j in range(bits.shape[0]):
                z[x, j] = 2.0 * ((bits[j, byte] >> sh) & 1) - 1.0
    else:
        for x in range(w):
            for j in range(noise.shape[0]):
                z[x, j] = noise[j, r, x]


@nb.njit(**INLINE, fastmath=FASTMATH)
def _copy(run, snap, e):
    """``snap[e] = run``, as a loop (a slice assignment compiles its shape
    checks for seconds)."""
    for q in range(run.shape[0]):
        for j in range(run.shape[1]):
            snap[e, q, j] = run[q, j]


@nb.njit(**INLINE, fastmath=FASTMATH)
def _row_sums(jx, jy, mask, r, z, order, edges, run, snap):
    """Running sums of ``jx n X^p`` and ``jy n X^p`` along row ``r`` (rows
    ``p`` and ``order + 1 + p`` of ``run``), kept in ``snap`` at each edge
    (the sums of the columns left of it)."""
    w = jx.shape[1]
    cx = 0.5 * (w - 1)
    nq, nk = run.shape
    for q in range(nq):
        for j in range(nk):
            run[q, j] = 0.0
    masked = mask.shape[0] > 0
    ne = edges.size
    ei = 0
    for x in range(w):
        while ei < ne and edges[ei] == x:
            _copy(run, snap, ei)
            ei += 1
        if masked and not mask[r, x]:
            continue
        xp = 1.0
        for p in range(order + 1):
            a = np.float64(jx[r, x]) * xp
            b = np.float64(jy[r, x]) * xp
            for j in range(z.shape[1]):
                run[p, j] += z[x, j] * a
                run[order + 1 + p, j] += z[x, j] * b
            xp *= x - cx
    while ei < ne:
        _copy(run, snap, ei)
        ei += 1


@nb.njit(**INLINE, fastmath=FASTMATH)
def _add(acc, c, out, k, sign):
    """``out[k] += sign * acc[c]``, as a loop."""
    for t in range(acc.shape[1]):
        for j in range(acc.shape[2]):
            out[k, t, j] += sign * acc[c, t, j]


@nb.njit(**CACHED, fastmath=FASTMATH)
def noise_window_sums(jx, jy, mask, bits, noise, order, edges, e0, e1, col_of, r0, r1,
                      by0, by1, out):
    """Raw window moments of every probe's products with ``jx`` and ``jy``.

    Parameters
    ----------
    jx, jy : (H, W) float32
        The steepest-descent images.
    mask : (H, W) bool or (0, 0)
        Pixels that count (none: all).
    bits : (K, ceil(H W / 8)) uint8 or (0, 0)
        The probes as packed ±1 bits (1: +1, 0: -1), or no rows: ``noise``.
    noise : (K, H, W) float32 or (0, 0, 0)
        The probes as images (used when ``bits`` has no rows).
    order : int
        Highest ``p + q`` (``<= MAX_NOISE_ORDER``).
    edges : (E,) int64
        Sorted distinct window edges (column indices, ``<= W``).
    e0, e1 : (C,) int64
        Per distinct node column, the indices in ``edges`` of its window's first
        column and of the column past its last.
    col_of : (N,) int64
        Each node's distinct column.
    r0, r1 : (N,) int64
        Each node's window rows ``r0 <= row < r1`` (``r0 < r1``).
    by0, by1 : (N,) int64
        The nodes ordered by ``r0`` and by ``r1``.
    out : (N, 2 M, K) float64
        Receives ``Σ jx n X^p Y^q`` (the first ``M`` rows, ``(p, q)`` in
        ``moments.moment_terms(order)`` order) and the same for ``jy``, with
        ``X``, ``Y`` about the image centre ``((W-1)/2, (H-1)/2)`` (the
        caller moves them to each node).
    """
    h, w = jx.shape
    nk = bits.shape[0] if bits.shape[0] > 0 else noise.shape[0]
    nt = (order + 1) * (order + 2) // 2
    n = col_of.size
    z = np.empty((w, nk))
    run = np.zeros((2 * (order + 1), nk))
    snap = np.empty((edges.size, 2 * (order + 1), nk))
    acc = np.zeros((e0.size, 2 * nt, nk))
    for k in range(n):
        for t in range(2 * nt):
            for j in range(nk):
                out[k, t, j] = 0.0
    i0 = i1 = 0
    for r in range(h):
        while i0 < n and r0[by0[i0]] == r:  # windows opening: less the sums so far
            _add(acc, col_of[by0[i0]], out, by0[i0], -1.0)
            i0 += 1
        if i1 == n:
            break
        if i0 == i1:  # no window open: this row's sums would cancel
            continue
        _noise_row(bits, noise, r, w, z)
        _row_sums(jx, jy, mask, r, z, order, edges, run, snap)
        y = r - 0.5 * (h - 1)
        for c in range(e0.size):
            for s in range(2):
                t = s * nt
                for p in range(order + 1):
                    yq = 1.0
                    for _q in range(order + 1 - p):
                        for j in range(nk):
                            acc[c, t, j] += (snap[e1[c], s * (order + 1) + p, j]
                                             - snap[e0[c], s * (order + 1) + p, j]) * yq
                        yq *= y
                        t += 1
        while i1 < n and r1[by1[i1]] == r + 1:  # windows closing: plus the sums now
            _add(acc, col_of[by1[i1]], out, by1[i1], 1.0)
            i1 += 1
