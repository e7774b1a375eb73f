"""Weighted window moments of pixel products, in one streaming pass.

For square windows centred on nodes of a lattice, the sums
``Σ_window a X^p Y^q`` (``X``, ``Y`` image-centred pixel coordinates,
``p + q <= order``) of several product images ``a = b_i b_j`` (or
``hypot(b_i, b_j)``) of a few base images ``b`` at once, optionally times a
binary mask -- without ever forming a product image. The speckle quality
and the Gauss-Newton matrices of the uncertainty (``dic.quality``) use them.

The image is read once, row by row. The window edges of the distinct node
columns cut each row into segments; per row and product, the sums of
``a X^p`` over each segment (the product formed one row at a time, in a
row buffer), added up over a window's segments, give the row's window
sums; these times
``Y^q`` are added to one accumulator per (distinct column, moment). A
node's moments are the accumulator after its window's last row less the
accumulator before its first row. To keep the cancellation of these
differences local (as small as the sums of one window, not of a whole row
or column), the running sums over segments restart every :data:`SBLOCK`
segments and the accumulators every :data:`EPOCH` rows (the windows open
across a restart carry the accumulator over). Memory:
``O(nodes x moments + threads x (distinct columns x moments + width))``.
Moments about each node follow from these by the binomial expansion
(:func:`centre_moments`). Bands of rows that start where the accumulators
restart anyway can run side by side (one kernel call each, on threads:
``dic.window_moments``, the wrapper that lays them out), each on the nodes
whose windows start in it (and shifted to them there): the same bits as one
pass over all rows.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import CALLEE, FASTMATH, INLINE, SERIAL

__all__ = ["ONES", "PRODUCT", "HYPOT", "MAX_IMAGES", "MAX_ORDER", "EPOCH", "moment_terms",
           "moments_kernel", "centre_moments"]

#: base index of an image of ones (``(ONES, ONES)`` is the mask itself)
ONES = -1
#: product kinds: ``b_i * b_j`` and ``hypot(b_i, b_j)``
PRODUCT, HYPOT = 0, 1
#: at most this many base images
MAX_IMAGES = 5
#: highest moment order ``p + q``
MAX_ORDER = 4
#: the running sums of the segments of a row restart every SBLOCK segments ...
SBLOCK = 16
#: ... and the column accumulators every EPOCH rows
EPOCH = 64
_ONES_ROW = MAX_IMAGES
_MASK_ROW = MAX_IMAGES + 1


def moment_terms(order: int) -> list:
    """The exponents ``(p, q)`` with ``p + q <= order``, in the kernel's order."""
    return [(p, q) for p in range(order + 1) for q in range(order + 1 - p)]


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _copy_row(dst, src, i):
    """``dst[:] = src[i, :]`` as float64 (any input dtype)."""
    for j in range(dst.size):
        dst[j] = src[i, j]


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _load_rows(i, a0, a1, a2, a3, a4, mask, used, rows):
    """Row ``i`` of every used base image and of the mask into ``rows``
    (float64; row :data:`_ONES_ROW` holds ones and is left alone)."""
    if used[0]:
        _copy_row(rows[0], a0, i)
    if used[1]:
        _copy_row(rows[1], a1, i)
    if used[2]:
        _copy_row(rows[2], a2, i)
    if used[3]:
        _copy_row(rows[3], a3, i)
    if used[4]:
        _copy_row(rows[4], a4, i)
    if mask.size:  # else the mask row keeps its ones
        m = rows[_MASK_ROW]
        for j in range(m.size):
            m[j] = 1.0 if mask[i, j] else 0.0


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _product_row(rows, ia, ib, kind, out):
    """One row of the product image ``b_ia b_ib`` (or their hypot), masked
    (the mask row holds ones when there is no mask)."""
    u, v, m = rows[ia], rows[ib], rows[_MASK_ROW]
    if kind == HYPOT:
        for j in range(out.size):
            out[j] = np.sqrt(u[j] * u[j] + v[j] * v[j]) * m[j]
    else:
        for j in range(out.size):
            out[j] = u[j] * v[j] * m[j]


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _segment_sums(a, xs, edges, order, seg):
    """``seg[p, s]``: sum of ``a X^p`` over columns ``[edges[s], edges[s + 1])``
    for ``p <= order`` (one loop per order range, the powers as independent
    chains: no add-latency stall)."""
    for s in range(edges.size - 1):
        s0 = s1 = s2 = s3 = s4 = 0.0
        if order == 0:
            for j in range(edges[s], edges[s + 1]):
                s0 += a[j]
        elif order <= 2:
            for j in range(edges[s], edges[s + 1]):
                x = xs[j]
                a0 = a[j]
                a1 = a0 * x
                s0 += a0
                s1 += a1
                s2 += a1 * x
        else:
            for j in range(edges[s], edges[s + 1]):
                x = xs[j]
                a0 = a[j]
                a1 = a0 * x
                a2 = a1 * x
                a3 = a2 * x
                s0 += a0
                s1 += a1
                s2 += a2
                s3 += a3
                s4 += a3 * x
        seg[0, s] = s0
        seg[1, s] = s1
        seg[2, s] = s2
        seg[3, s] = s3
        seg[4, s] = s4


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _segment_prefix(seg, nseg, order, loc, btot):
    """Running sums of the segment sums, restarting every SBLOCK segments:
    ``loc[p, s]`` sums the segments of ``s``'s block before ``s``,
    ``btot[p, b]`` is block ``b``'s total (``loc[:, nseg]`` belongs to block
    ``nseg // SBLOCK``)."""
    nblk = nseg // SBLOCK + 1
    for p in range(order + 1):
        for b in range(nblk):
            run = 0.0
            for s in range(b * SBLOCK, min(b * SBLOCK + SBLOCK, nseg)):
                loc[p, s] = run
                run += seg[p, s]
            btot[p, b] = run
        loc[p, nseg] = btot[p, nblk - 1]


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _add_row(acc, loc, btot, e0, e1, order, off, ypow, band):
    """Add the row's window sums (segments ``[e0, e1)`` of each distinct
    column ``c``, from the block running sums) times ``Y^q`` to the column
    accumulators ``acc[off + t, c]`` (moments ``t`` in :func:`moment_terms`
    order; the last loop runs along the columns and vectorises)."""
    nc = e0.size
    for c in range(nc):
        s0, s1 = e0[c], e1[c]
        b0, b1 = s0 // SBLOCK, s1 // SBLOCK
        for p in range(order + 1):
            if b0 == b1:
                band[p, c] = loc[p, s1] - loc[p, s0]
            else:
                s = btot[p, b0] - loc[p, s0]
                for b in range(b0 + 1, b1):
                    s += btot[p, b]
                band[p, c] = s + loc[p, s1]
    t = off
    for p in range(order + 1):
        bp = band[p]
        for q in range(order + 1 - p):
            y = ypow[q]
            a = acc[t]
            for c in range(nc):
                a[c] += bp[c] * y
            t += 1


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _flush(out, acc, node, col, sign):
    """``out[node, :] += sign * acc[:, col]`` (every moment)."""
    for k in range(out.shape[1]):
        out[node, k] += sign * acc[k, col]


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _close_windows(b, r0, r1, by1, p1, col_of, out, acc):
    """Nodes whose window ends before row ``b`` (``by1``: nodes by ``r1``,
    from position ``p1``) take the accumulator; the next position."""
    n = by1.size
    while p1 < n and r1[by1[p1]] == b:
        nd = by1[p1]
        if r0[nd] < b:
            _flush(out, acc, nd, col_of[nd], 1.0)
        p1 += 1
    return p1


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _restart(b, r0, r1, by0, lo, tall, col_of, out, acc):
    """Restart the accumulator at row ``b`` (bounds its cancellation): the
    windows open across ``b`` keep what they have so far. Windows taller
    than ``tall`` do not exist, so the scan starts at ``lo``; its update."""
    n = by0.size
    while lo < n and r0[by0[lo]] <= b - tall:
        lo += 1
    t = lo
    while t < n and r0[by0[t]] < b:
        nd = by0[t]
        if r1[nd] > b:
            _flush(out, acc, nd, col_of[nd], 1.0)
        t += 1
    acc[:] = 0.0
    return lo


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _open_windows(b, r0, r1, by0, p0, col_of, out, acc):
    """Nodes whose window starts at row ``b`` give back what the accumulator
    holds so far; the next position in ``by0`` (nodes by ``r0``)."""
    n = by0.size
    while p0 < n and r0[by0[p0]] == b:
        nd = by0[p0]
        if r1[nd] > b:
            _flush(out, acc, nd, col_of[nd], -1.0)
        p0 += 1
    return p0


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _add_image_row(b, a0, a1, a2, a3, a4, mask, used, products, offs, edges, e0, e1, xs,
                   y, acc, work):
    """Add row ``b`` (at coordinate ``Y = y``) of every product to the
    per-column accumulators. ``work``: scratch arrays (base rows, product
    row, segment sums, their prefixes and block totals, band, powers of y)."""
    rows, prow, seg, loc, btot, band, ypow = work
    nseg = seg.shape[1]
    _load_rows(b, a0, a1, a2, a3, a4, mask, used, rows)
    ypow[0] = 1.0
    for q in range(1, MAX_ORDER + 1):
        ypow[q] = ypow[q - 1] * y
    for k in range(products.shape[0]):
        ia = products[k, 0] if products[k, 0] >= 0 else _ONES_ROW
        ib = products[k, 1] if products[k, 1] >= 0 else _ONES_ROW
        order = products[k, 3]
        _product_row(rows, ia, ib, products[k, 2], prow)
        _segment_sums(prow, xs, edges, order, seg)
        _segment_prefix(seg, nseg, order, loc, btot)
        _add_row(acc, loc, btot, e0, e1, order, offs[k], ypow, band)


@nb.njit(**SERIAL, fastmath=FASTMATH)
def moments_kernel(a0, a1, a2, a3, a4, mask, used, products, offs, edges, e0, e1, col_of, r0,
                   r1, xs, ys, nodes, by1, start, tall, dx, dy, out):
    """Window moments of pixel products per node, streaming over the rows.

    For each node ``n`` and product ``k`` (base images ``b_i``, ``b_j``;
    index :data:`ONES` is an image of ones), the sums over the window
    ``rows [r0[n], r1[n]) x columns [edges[e0[c]], edges[e1[c]])``
    (``c = col_of[n]``) of
    ``a_k X^p Y^q`` with ``a_k = b_i b_j`` (kind PRODUCT) or
    ``hypot(b_i, b_j)`` (kind HYPOT), times the mask when one is given, for
    every ``p + q <= order_k`` (:func:`moment_terms` order). One pass over
    the rows: segment sums between window edges (their running sums
    restarted every SBLOCK segments) give the row's sums over the distinct
    column windows, accumulated per
    column (restarted every EPOCH rows, the open windows carrying over);
    each node takes the accumulator at ``r1`` less that at ``r0``. One call
    does one band of rows (whole epochs, by the nodes' first rows;
    ``dic.window_moments`` runs bands side by side on threads): a band starts
    where the accumulator restarts anyway, so each node comes out as from one
    pass over all rows.

    Parameters
    ----------
    a0, a1, a2, a3, a4 : (H, W) float arrays
        Base images (any float dtype; unused ones may be empty).
    mask : (H, W) bool or (0, 0) bool
        Binary mask multiplied into every product; empty: none.
    used : (MAX_IMAGES,) bool
        The base images the products use.
    products : (P, 4) int64
        Per product ``(i, j, kind, order)``; ``order <= MAX_ORDER``.
    offs : (P + 1,) int64
        Where each product's moments start in a node's row of ``out``.
    edges : (E,) int64
        Sorted distinct window edges (columns, within the image).
    e0, e1 : (C,) int64
        Column window of each distinct node column: edges ``e0`` to ``e1``.
    col_of : (N,) int64
        Distinct column of each node.
    r0, r1 : (N,) int64
        Row window ``[r0, r1)`` of each node, within the image.
    xs, ys : (W,), (H,) float64
        Coordinate ``X`` of each column and ``Y`` of each row.
    dx, dy : (N,) or (0,) float64
        When given, each node's position: its moments are returned about
        it (:func:`centre_moments`) instead of about the origin.
    nodes, by1 : (B,) int64
        The band's nodes by first row (all at or after row ``start``) and
        by last row.
    start : int
        The band's first row (a multiple of :data:`EPOCH`).
    tall : int
        The tallest window (rows) of all nodes.
    out : (N, M) float64, zeroed
        Receives, at the band's rows, per node the moments of product 0,
        then those of product 1, ... (``M = Σ_k (order_k + 1)(order_k + 2) / 2``).

    """
    if nodes.size:
        _stream_band(a0, a1, a2, a3, a4, mask, used, products, offs, edges, e0, e1, col_of,
                     r0, r1, xs, ys, nodes, by1, start, tall, out)
        if dx.size:
            _centre_rows(out, nodes, products[:, 3], offs, dx, dy)


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _stream_band(a0, a1, a2, a3, a4, mask, used, products, offs, edges, e0, e1, col_of,
                 r0, r1, xs, ys, by0, by1, start, tall, out):
    """The moments of the nodes ``by0`` (sorted by ``r0``, all ``r0 >=
    start``; ``start`` a multiple of :data:`EPOCH`; ``by1``: the same nodes
    sorted by ``r1``) from rows ``start`` on."""
    nseg = max(edges.size - 1, 0)
    acc = np.zeros((offs[-1], e0.size))
    work = (np.ones((MAX_IMAGES + 2, xs.size)), np.empty(xs.size),
            np.zeros((MAX_ORDER + 1, nseg)), np.zeros((MAX_ORDER + 1, nseg + 1)),
            np.zeros((MAX_ORDER + 1, nseg // SBLOCK + 1)), np.empty((MAX_ORDER + 1, e0.size)),
            np.empty(MAX_ORDER + 1))
    stop = r1[by1[-1]]
    p0 = p1 = lo = np.int64(0)  # not a literal 0: the helpers would compile twice
    for b in range(start, stop + 1):
        p1 = _close_windows(b, r0, r1, by1, p1, col_of, out, acc)
        if b == stop:  # every window of the band is closed
            break
        if b % EPOCH == 0 and b > start:
            lo = _restart(b, r0, r1, by0, lo, tall, col_of, out, acc)
        p0 = _open_windows(b, r0, r1, by0, p0, col_of, out, acc)
        _add_image_row(b, a0, a1, a2, a3, a4, mask, used, products, offs, edges, e0, e1,
                       xs, ys[b], acc, work)


@nb.njit(**CALLEE)
def _binomials():
    """Binomial coefficients ``C(p, i)``, ``p, i <= MAX_ORDER``."""
    binom = np.zeros((MAX_ORDER + 1, MAX_ORDER + 1))
    for p in range(MAX_ORDER + 1):
        binom[p, 0] = 1.0
        for i in range(1, p + 1):
            binom[p, i] = binom[p - 1, i - 1] + binom[p - 1, i]
    return binom


@nb.njit(**INLINE)
def _centre_node(raw, out, dx, dy, order, binom, px, py):
    """``out``: the moments ``raw`` (one node, one product, up to ``order``)
    about the point ``(dx, dy)``, by the binomial expansion."""
    px[0] = py[0] = 1.0
    for i in range(1, order + 1):
        px[i] = -dx * px[i - 1]
        py[i] = -dy * py[i - 1]
    for p in range(order + 1):
        for q in range(order + 1 - p):
            m = 0.0
            for i in range(p + 1):
                si = i * (order + 1) - i * (i - 1) // 2  # column of (i, 0)
                for j in range(q + 1):
                    m += binom[p, i] * binom[q, j] * px[p - i] * py[q - j] * raw[si + j]
            out[p * (order + 1) - p * (p - 1) // 2 + q] = m


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _centre_rows(out, nodes, orders, offs, dx, dy):
    """Rows ``nodes`` of ``out`` (the moments of each product, ``orders``,
    from column ``offs``) taken about each node, in place."""
    binom = _binomials()
    px, py = np.empty(MAX_ORDER + 1), np.empty(MAX_ORDER + 1)
    raw = np.empty(offs[-1])
    for nd in nodes:
        for j in range(raw.size):  # (not raw[:] = ...: its shape check compiles for 1.9 s)
            raw[j] = out[nd, j]
        for k in range(orders.size):
            a, b = offs[k], offs[k + 1]
            _centre_node(raw[a:b], out[nd, a:b], dx[nd], dy[nd], orders[k], binom, px, py)


# serial (issue 25): a few milliseconds per run, 0.6 s less compiling
@nb.njit(**SERIAL, fastmath=FASTMATH)
def centre_moments(raw, dx, dy, order):
    """Moments about each node from moments about the origin.

    The binomial expansion ``Σ a (X - dx)^p (Y - dy)^q = Σ_ij C(p, i) C(q, j)
    (-dx)^(p-i) (-dy)^(q-j) Σ a X^i Y^j``, node by node.

    Parameters
    ----------
    raw : (N, M) float64
        Moments ``Σ a X^p Y^q`` of one product, in :func:`moment_terms` order.
    dx, dy : (N,) float64
        Each node's position in the coordinates of ``raw``.
    order : int
        Highest ``p + q`` (``M = (order + 1)(order + 2) / 2``).

    Returns
    -------
    (N, M) float64
        The moments about each node.
    """
    n = raw.shape[0]
    out = np.empty((n, raw.shape[1]))  # every entry is written
    binom = _binomials()
    px, py = np.empty(order + 1), np.empty(order + 1)
    for k in range(n):
        _centre_node(raw[k], out[k], dx[k], dy[k], order, binom, px, py)
    return out
