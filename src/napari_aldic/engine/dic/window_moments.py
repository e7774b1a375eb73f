"""Window moments ``Σ a X^p Y^q`` of pixel products at lattice nodes: the
wrapper of the streaming kernel :func:`~..kernels.moments.moments_kernel`,
which lays out its bands of rows and runs them side by side on threads (the
kernel is serial and releases the GIL: a ``prange`` kernel took 3.5 s longer
to compile on a first run)."""

from __future__ import annotations

import numba
import numpy as np

from ..kernels.moments import EPOCH, MAX_IMAGES, MAX_ORDER, ONES, PRODUCT, moments_kernel
from .threads import side_by_side

__all__ = ["window_moments", "band_layout", "BANDS_PER_THREAD", "PARALLEL_WORK"]

#: row bands per thread in :func:`window_moments` (more balance the load, each
#: costs one window height of rows read twice) ...
BANDS_PER_THREAD = 2
#: ... for at least this many pixel products (fewer: one band, one thread;
#: starting threads on a busy machine can cost tens of milliseconds)
PARALLEL_WORK = 1 << 24


def band_layout(r0: np.ndarray, r1: np.ndarray, h: int, nband: int):
    """The bands of :func:`window_moments` (in NumPy: sorting and searching
    compiled in Numba cost ~3 s of a first run): ``by0`` the nodes by first
    row, ``by1`` each band's nodes by last row, ``cut`` where each band
    starts in ``by0``, ``tall`` the tallest window, ``height`` the band
    height (whole epochs)."""
    n = r0.size
    by0 = np.argsort(r0, kind="stable")
    tall = int(np.max(r1 - r0)) if n else 0
    height = EPOCH * max(1, -(-h // (EPOCH * max(nband, 1))))
    cut = np.searchsorted(r0[by0], np.arange(0, h + height, height)).astype(np.int64)
    cut[-1] = n
    by1 = np.empty_like(by0)
    for a, b in zip(cut[:-1], cut[1:]):
        band = by0[a:b]
        by1[a:b] = band[np.argsort(r1[band], kind="stable")]
    return by0, by1, cut, tall, height


def window_moments(images, products, x, y, half: int, *, mask=None, origin=None,
                   centre: bool = False, joined: bool = False, serial: bool = False):
    """Window moments ``Σ a X^p Y^q`` of pixel products at lattice nodes.

    Parameters
    ----------
    images : sequence of (H, W) float arrays
        Up to :data:`MAX_IMAGES` base images (not copied).
    products : sequence of tuples
        ``(i, j, order)`` or ``(i, j, order, kind)``: base indices (``ONES``
        for an image of ones), highest ``p + q`` (``<= MAX_ORDER``) and kind
        (:data:`PRODUCT`, the default, or :data:`HYPOT`).
    x, y : (N,) int-like
        Node coordinates (column, row).
    half : int
        Window half-width: columns ``x - half .. x + half`` clipped to the image.
    mask : (H, W) bool, optional
        Binary mask multiplied into every product.
    origin : (cx, cy), optional
        Coordinate origin (default: the image centre ``((W-1)/2, (H-1)/2)``).
    centre : bool
        Return the moments about each node instead (``X - x``, ``Y - y``;
        :func:`centre_moments` of the raw ones).
    joined : bool
        Return the one (N, Σ M_k) array the list below is made of.
    serial : bool
        One band on the calling thread, however large the job (for callers
        that run several calls side by side on their own threads).

    Returns
    -------
    list of (N, M_k) float64
        Per product, the moments ``(p, q)`` in :func:`moment_terms` order
        (views of one array).
    """
    images, prod, m = _checked(images, products, mask)
    h, w = images[0].shape
    cx, cy = ((w - 1) / 2.0, (h - 1) / 2.0) if origin is None else origin
    cols, col_of = np.unique(np.asarray(x, np.int64), return_inverse=True)
    yi = np.asarray(y, np.int64).ravel()
    c0, c1 = np.clip(cols - half, 0, w), np.clip(cols + half + 1, 0, w)
    edges = np.unique(np.concatenate([c0, c1]))
    dx = dy = np.zeros(0)
    if centre:
        dx = np.asarray(x, np.float64).ravel() - float(cx)
        dy = yi - float(cy)
    r0, r1 = np.clip(yi - half, 0, h), np.clip(yi + half + 1, 0, h)
    threads = numba.get_num_threads()
    nband = (BANDS_PER_THREAD * threads
             if h * w * len(prod) >= PARALLEL_WORK and not serial and threads > 1 else 1)
    by0, by1, cut, tall, height = band_layout(r0, r1, h, nband)
    orders = prod[:, 3]
    offs = np.concatenate([[0], np.cumsum((orders + 1) * (orders + 2) // 2)]).astype(np.int64)
    used = np.zeros(MAX_IMAGES, np.bool_)
    used[prod[:, :2][prod[:, :2] >= 0]] = True
    out = np.zeros((yi.size, int(offs[-1])))
    fixed = (*images, m, used, prod, offs, edges, np.searchsorted(edges, c0),
             np.searchsorted(edges, c1), col_of.ravel().astype(np.int64), r0, r1,
             np.arange(w) - float(cx), np.arange(h) - float(cy))

    def band(k: int) -> None:  # each band writes its own nodes' rows of out
        moments_kernel(*fixed, by0[cut[k]:cut[k + 1]], by1[cut[k]:cut[k + 1]],
                       k * height, tall, dx, dy, out)
    side_by_side(band, range(cut.size - 1), threads)
    if joined:
        return out
    res, k = [], 0
    for o in prod[:, 3]:
        m = (o + 1) * (o + 2) // 2
        res.append(out[:, k:k + m])
        k += m
    return res


def _checked(images, products, mask):
    """The kernel's inputs of :func:`window_moments`: the base images padded
    with empty ones to :data:`MAX_IMAGES`, the (P, 4) product table and the
    mask ((0, 0) for none); a ValueError naming what is wrong."""
    images = [np.asarray(a) for a in images]
    if not 1 <= len(images) <= MAX_IMAGES:
        raise ValueError(f"window_moments takes 1 to {MAX_IMAGES} images, got {len(images)}")
    h, w = images[0].shape
    if any(a.shape != (h, w) for a in images):
        raise ValueError("window_moments: the images differ in shape")
    prod = np.array([(int(t[0]), int(t[1]), int(t[3]) if len(t) > 3 else PRODUCT, int(t[2]))
                     for t in products], np.int64).reshape(-1, 4)
    if np.any(prod[:, :2] >= len(images)) or np.any(prod[:, :2] < ONES):
        raise ValueError("window_moments: a product names a missing image")
    if np.any(prod[:, 3] < 0) or np.any(prod[:, 3] > MAX_ORDER):
        raise ValueError(f"window_moments: moment orders must be 0..{MAX_ORDER}")
    images += [np.zeros((0, 0), images[0].dtype)] * (MAX_IMAGES - len(images))
    m = np.zeros((0, 0), np.bool_) if mask is None else np.asarray(mask, np.bool_)
    if mask is not None and m.shape != (h, w):
        raise ValueError(f"window_moments: mask shape {m.shape} differs from the images' "
                         f"{(h, w)}")
    return images, prod, m
