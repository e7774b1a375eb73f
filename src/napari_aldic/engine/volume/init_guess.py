"""Initial guess of DVC: FFT cross-correlation of a few blocks, then propagation.

Memory stays bounded by the search blocks: one central block fixes the
rigid shift of the whole volume; anchor nodes (a sparse sub-lattice) are
searched around it with a small range, solved by IC-GN, and every other
node starts from its nearest solved anchor's affine map extrapolated to the
node (exact for uniform strain and rotation).
"""

from __future__ import annotations

import numba
import numpy as np
from scipy import fft

__all__ = ["ncc_search", "global_shift"]


def _box_sums(a: np.ndarray, n: int) -> np.ndarray:
    """Sums of ``a`` over every ``n^3`` window (valid positions only)."""
    c = np.pad(a, ((1, 0), (1, 0), (1, 0))).cumsum(0).cumsum(1).cumsum(2)
    return (c[n:, n:, n:] - c[:-n, n:, n:] - c[n:, :-n, n:] - c[n:, n:, :-n]
            + c[:-n, :-n, n:] + c[:-n, n:, :-n] + c[n:, :-n, :-n] - c[:-n, :-n, :-n])


def ncc_search(ref, dfm, centre, half: int, search: int, shift0=(0, 0, 0)):
    """Integer shift of the ``(2 half + 1)^3`` reference block at ``centre``
    (x, y, z) that maximises the ZNCC in ``dfm`` within ``search`` voxels of
    ``shift0`` (x, y, z).

    Returns ``(shift (3,) int, peak ZNCC, on_border)``; ``on_border`` is True
    when the peak lies on the edge of the tested range (motion may be beyond it).
    """
    c = np.asarray(centre, int)[::-1]  # z, y, x
    s0 = np.asarray(shift0, int)[::-1]
    shape = np.array(ref.shape)
    lo_t, hi_t = c - half, c + half + 1
    T = np.asarray(ref[lo_t[0]:hi_t[0], lo_t[1]:hi_t[1], lo_t[2]:hi_t[2]], np.float64)
    T = T - T.mean()
    tn = np.sqrt((T * T).sum())
    lo_w = np.clip(lo_t + s0 - search, 0, shape)
    hi_w = np.clip(hi_t + s0 + search, 0, shape)
    n = 2 * half + 1
    if np.any(hi_w - lo_w < n) or tn == 0:
        return np.asarray(shift0, int), -1.0, True
    W = np.asarray(dfm[lo_w[0]:hi_w[0], lo_w[1]:hi_w[1], lo_w[2]:hi_w[2]], np.float64)
    size = W.shape
    fast = [fft.next_fast_len(s, real=True) for s in size]  # 37 is prime: pad to 40
    workers = numba.get_num_threads()  # the run's threads (n_threads)
    corr = fft.irfftn(fft.rfftn(W, fast, workers=workers)
                      * np.conj(fft.rfftn(T, fast, workers=workers)), fast, workers=workers)
    valid = tuple(slice(0, s - n + 1) for s in size)
    corr = corr[valid]
    s1 = _box_sums(W, n)
    s2 = _box_sums(W * W, n)
    var = np.maximum(s2 - s1 * s1 / n**3, 1e-12)
    zn = corr / (np.sqrt(var) * tn)
    k = np.unravel_index(int(np.argmax(zn)), zn.shape)
    shift = (lo_w + np.array(k)) - lo_t  # z, y, x
    # on the edge of the tested range (not where the volume's face clipped it)
    border = bool(np.any(np.abs(shift - s0) >= search))
    return shift[::-1].astype(int), float(zn[k]), border


def global_shift(ref, dfm, search: int, search_max: int):
    """Rigid shift (x, y, z) of the central block, widening the search while
    its peak is on the border of the range. Returns ``(shift, zncc)``."""
    shape = np.array(ref.shape)
    half = int(max(min(shape.min() // 4, 32), 4))
    centre = (shape // 2)[::-1]
    s = max(int(search), 2)
    while True:
        room = int(min(s, (shape.min() - 2 * half - 1) // 2))
        shift, zn, border = ncc_search(ref, dfm, centre, half, max(room, 1))
        if not border or s >= search_max or room < s:
            return shift, zn
        s *= 2
