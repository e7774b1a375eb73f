"""Speckle pairs of any size with exact truth, written tile by tile (bench_scale.py).

Rendering the analytic speckle of :mod:`napari_aldic.engine.synthetic` costs about
a second per megapixel on this machine (area means of Gaussian blobs), far too
slow for 40,000² pairs. So the analytic speckle is rendered once on a periodic
``PERIOD``² cell (blobs near the edges wrapped around), and the pair is built
from that cell's cubic B-spline, a smooth image defined everywhere:

* reference pixel (row i, col j) = the cell at ``(j mod P, i mod P)`` (the
  spline interpolates the cell, so this is exact);
* deformed pixel = the spline at the material point ``X = x - u(X)`` (the
  affine field is inverted exactly), taken modulo P;

then 0.5 grey level of Gaussian noise and rounding to 8 bits. The period (2048
px) is far beyond any subset or search range. Each 512² tile is computed on
its own, so a 40,000² BigTIFF is written from a generator in bounded memory.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

PERIOD = 2048
TILE = 512
#: the known smooth field: 0.05 % strain, shear, a (2.3, -1.7) px translation
#: at the image centre (up to ~15 px at the corners of a 40k image)
FIELD_G = ((5e-4, 2e-4), (-1e-4, 3e-4))
NOISE = 0.5


def field(shape):
    from napari_aldic.engine import synthetic as S

    return S.Affine(G=FIELD_G, center=(shape[1] / 2, shape[0] / 2), t=(2.3, -1.7))


def periodic_cell(seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """A ``PERIOD``² periodic speckle cell and its cubic B-spline coefficients."""
    from napari_aldic.engine import synthetic as S

    P = PERIOD
    pat = S.make_pattern((P, P), seed=seed, margin=0.0)
    xs, ys, sg, amp = [], [], [], []
    for dy in (-P, 0, P):
        for dx in (-P, 0, P):
            x, y = pat.x + dx, pat.y + dy
            near = (x > -24) & (x < P + 24) & (y > -24) & (y < P + 24)
            xs.append(x[near]), ys.append(y[near]), sg.append(pat.sigma[near])
            amp.append(pat.amp[near])
    x, y, sigma, a = map(np.concatenate, (xs, ys, sg, amp))
    x0 = y0 = -24.0
    bin_size = float(4.0 * sigma.max())
    nb = int(np.ceil((P + 48) / bin_size)) + 1
    b = (np.floor((y - y0) / bin_size) * nb + np.floor((x - x0) / bin_size)).astype(np.int64)
    order = np.argsort(b, kind="stable")
    start = np.zeros(nb * nb + 1, np.int64)
    np.cumsum(np.bincount(b, minlength=nb * nb), out=start[1:])
    wrapped = S.SpecklePattern(x[order], y[order], sigma[order], a[order], pat.lo, pat.hi,
                               bin_size, start, np.arange(x.size), (x0, y0), (nb, nb))
    cell = S.render(wrapped, (P, P), None, n_quad=4, bit_depth=None)
    return cell, ndimage.spline_filter(cell, order=3, mode="grid-wrap")


def _tile(cell, fld, r0, c0, h, w, deformed: bool, rng) -> np.ndarray:
    """One tile: the cell itself (reference), or its spline at the material
    points of the deformed pixels (``ndimage.affine_transform`` with the
    exact inverse of the affine map, wrapped around the period)."""
    if deformed:
        G = np.asarray(FIELD_G)
        A = np.linalg.inv(np.eye(2) + G)  # X = A (x - t + G c)
        off = A @ (np.array([c0, r0], float) - np.asarray(fld.t) + G @ np.asarray(fld.center))
        vals = ndimage.affine_transform(cell, A[::-1, ::-1], offset=off[::-1],
                                        output_shape=(h, w), order=3, mode="grid-wrap",
                                        prefilter=False)
    else:
        vals = cell[np.ix_(np.arange(r0, r0 + h) % PERIOD, np.arange(c0, c0 + w) % PERIOD)]
    vals = vals + rng.normal(0.0, NOISE, vals.shape)
    return np.clip(np.rint(vals), 0, 255).astype(np.uint8)


def tiles(cells, shape, deformed: bool, seed: int, threads: int = 2):
    """The image's 512² tiles, row by row (tifffile's order), ``threads`` at a time."""
    from concurrent.futures import ThreadPoolExecutor

    fld = field(shape)
    src = cells[1] if deformed else cells[0]

    def one(rc):
        r0, c0 = rc
        rng = np.random.default_rng([seed, int(deformed), r0, c0])
        h, w = min(TILE, shape[0] - r0), min(TILE, shape[1] - c0)
        t = _tile(src, fld, r0, c0, h, w, deformed, rng)
        return np.pad(t, ((0, TILE - h), (0, TILE - w)))  # edge tiles are padded

    with ThreadPoolExecutor(threads) as pool:
        for r0 in range(0, shape[0], TILE):  # one row of tiles in flight at a time
            yield from pool.map(one, [(r0, c0) for c0 in range(0, shape[1], TILE)])


def write_pair(folder: Path, size: int, seed: int = 7) -> tuple[Path, Path]:
    """``ref.tif``/``def.tif`` of ``size``² as tiled uint8 BigTIFF."""
    import tifffile

    folder.mkdir(parents=True, exist_ok=True)
    cells = periodic_cell(seed)
    paths = []
    for name, deformed in (("ref", False), ("def", True)):
        p = folder / f"{name}_{size}.tif"
        if not p.exists():
            tmp = p.with_suffix(".part")
            tifffile.imwrite(tmp, tiles(cells, (size, size), deformed, seed),
                             shape=(size, size), dtype=np.uint8, tile=(TILE, TILE),
                             bigtiff=True, photometric="minisblack")
            tmp.rename(p)
        paths.append(p)
    return paths[0], paths[1]


def errors(res) -> dict:
    """RMS and largest error (px) of the valid nodes against the exact field."""
    u, v = field(res.image_shape).displacement(res.x, res.y)
    ok = res.valid
    du, dv = res.u[ok] - u[ok], res.v[ok] - v[ok]
    return {"nodes": len(res), "valid": int(ok.sum()),
            "rms_error_px": float(np.sqrt(np.mean(du**2 + dv**2))),
            "max_error_px": float(np.max(np.hypot(du, dv)))}
