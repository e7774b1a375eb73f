"""Adaptive quadtree meshes with hanging nodes and composable refinement criteria.

The base mesh is the uniform Q4 mesh of the node lattice (element size =
``step``). Flagged elements are split into four children, recursively, down
to a minimum element size; the mesh is kept 1-irregular (2:1 balanced: edge
neighbours differ by at most one level) by also splitting coarse neighbours
of refined elements. A node in the middle of a coarse element's edge is a
*hanging node*: the global solve constrains it to the mean of that edge's
end nodes, so the displacement stays continuous across level transitions.
Every node, hanging or not, is a DIC point with its own subset.

Refinement criteria (any combination, see :class:`Refinement`):

1. ``mask_boundary`` -- elements near holes or cracks inside the ROI
   (components of the excluded area that do not touch the image border);
2. ``roi_boundary`` -- elements near the outer outline of the ROI;
3. ``brush`` -- elements touching a painted boolean region;
4. ``elements`` / ``points`` -- manual selection by element index or by
   points (x, y) lying inside elements;
5. ``error`` -- a-posteriori: after a first pass, elements with a corner
   node whose correlation is poor (not converged or ZNCC below the
   threshold used for flagging) are refined and the analysis is repeated.

Presets: ``"light"`` (mask boundary, one level), ``"medium"`` (mask and ROI
boundaries, two levels), ``"strong"`` (mask and ROI boundaries plus the
correlation-error criterion, three levels). Element sizes never go below
``min_size`` pixels, and stay even so node coordinates stay integer.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from ..core.reasons import DICError
from .global_solve import Q4Mesh, element_inside_roi
from .subsets import integral_image, rect_sums

__all__ = ["Refinement", "resolve_refinement", "QuadMesh", "build_quadtree", "PRESETS"]


@dataclass(frozen=True)
class Refinement:
    """Which elements to refine, and how far.

    Attributes
    ----------
    mask_boundary : bool
        Refine near holes/cracks inside the ROI.
    roi_boundary : bool
        Refine near the ROI's outer outline.
    brush : (H, W) bool array or None
        Painted region: refine elements touching it.
    elements : tuple of int
        Base-mesh element indices to refine (row-major over lattice cells).
    points : tuple of (x, y)
        Refine the elements containing these points (pixels).
    error : bool
        A-posteriori refinement where correlation is poor after a first pass.
    levels : int
        Maximum number of splits of a base element (>= 1).
    min_size : int
        Smallest element side in pixels (even, >= 2).
    margin : float or None
        Distance in pixels from a boundary within which elements count as
        "near" it; None uses half the subset width.
    """

    mask_boundary: bool = False
    roi_boundary: bool = False
    brush: np.ndarray | None = field(default=None, compare=False, repr=False)
    elements: tuple = ()
    points: tuple = ()
    error: bool = False
    levels: int = 2
    min_size: int = 2
    margin: float | None = None

    def any(self) -> bool:
        return bool(self.mask_boundary or self.roi_boundary or self.brush is not None
                    or len(self.elements) or len(self.points) or self.error)


PRESETS = {
    "light": Refinement(mask_boundary=True, levels=1),
    "medium": Refinement(mask_boundary=True, roi_boundary=True, levels=2),
    "strong": Refinement(mask_boundary=True, roi_boundary=True, error=True, levels=3),
}


def resolve_refinement(refine) -> Refinement | None:
    """``None``/``"none"``, a preset name, a :class:`Refinement` or a dict."""
    if refine is None or (isinstance(refine, str) and refine.lower() == "none"):
        return None
    if isinstance(refine, Refinement):
        return refine
    if isinstance(refine, str):
        key = refine.lower()
        if key not in PRESETS:
            raise ValueError(f"refine={refine!r}: choose None, one of {sorted(PRESETS)}, "
                             "or a Refinement")
        return PRESETS[key]
    if isinstance(refine, dict):
        return Refinement(**refine)
    raise ValueError(f"refine={refine!r} is not a preset name, dict or Refinement")


@dataclass
class QuadMesh:
    """A (possibly refined) Q4 mesh and its DIC nodes."""

    mesh: Q4Mesh  # elements and hanging constraints over all nodes
    base_index: np.ndarray  # (N,) index of the node in the base lattice grid, -1 if new
    cells: np.ndarray  # (E, 3) int: x0, y0, size of every leaf element (all, even outside ROI)


def _boundary_maps(roi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(near_holes, near_outline): ROI pixels adjacent to interior holes / to the outside."""
    excluded = ~roi
    lab, n = ndimage.label(excluded)
    border = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    outside = np.isin(lab, border[border > 0])
    holes = excluded & ~outside
    # the image frame itself is not an ROI boundary worth refining
    grow_h = ndimage.binary_dilation(holes)
    grow_o = ndimage.binary_dilation(outside)
    return roi & grow_h, roi & grow_o


def _rect_hits(ii: np.ndarray, x0, y0, x1, y1) -> np.ndarray:
    h, w = ii.shape[0] - 1, ii.shape[1] - 1
    x0 = np.clip(np.floor(x0).astype(np.int64), 0, w - 1)
    y0 = np.clip(np.floor(y0).astype(np.int64), 0, h - 1)
    x1 = np.clip(np.ceil(x1).astype(np.int64), 0, w - 1)
    y1 = np.clip(np.ceil(y1).astype(np.int64), 0, h - 1)
    return rect_sums(ii, x0, y0, x1, y1) > 0


def flag_elements(cells: np.ndarray, roi: np.ndarray, ref: Refinement, half: int,
                  base_shape: tuple[int, int] | None = None,
                  bad_nodes_xy: np.ndarray | None = None) -> np.ndarray:
    """Boolean flags of ``cells`` (x0, y0, size) under the geometric criteria
    (and the error criterion when ``bad_nodes_xy`` is given)."""
    x0 = cells[:, 0].astype(float)
    y0 = cells[:, 1].astype(float)
    s = cells[:, 2].astype(float)
    m = float(half if ref.margin is None else ref.margin)
    flags = np.zeros(cells.shape[0], bool)
    if ref.mask_boundary or ref.roi_boundary:
        near_h, near_o = _boundary_maps(roi)
        for on, img in ((ref.mask_boundary, near_h), (ref.roi_boundary, near_o)):
            if on and img.any():
                flags |= _rect_hits(integral_image(img.view(np.uint8)), x0 - m, y0 - m,
                                    x0 + s + m, y0 + s + m)
    if ref.brush is not None:
        b = np.asarray(ref.brush, bool)
        if b.shape != roi.shape:
            raise DICError("shape_mismatch", f"brush region shape {b.shape} differs from image "
                           f"shape {roi.shape}", what="brush", shape=b.shape,
                           image_shape=roi.shape)
        flags |= _rect_hits(integral_image(b.view(np.uint8)), x0, y0, x0 + s, y0 + s)
    if len(ref.points):
        pts = np.asarray(ref.points, float).reshape(-1, 2)
        inside = ((pts[None, :, 0] >= x0[:, None]) & (pts[None, :, 0] <= (x0 + s)[:, None])
                  & (pts[None, :, 1] >= y0[:, None]) & (pts[None, :, 1] <= (y0 + s)[:, None]))
        flags |= inside.any(axis=1)
    if bad_nodes_xy is not None and len(bad_nodes_xy):
        bx = bad_nodes_xy[:, 0]
        by = bad_nodes_xy[:, 1]
        near = ((bx[None, :] >= x0[:, None]) & (bx[None, :] <= (x0 + s)[:, None])
                & (by[None, :] >= y0[:, None]) & (by[None, :] <= (y0 + s)[:, None]))
        flags |= near.any(axis=1)
    return flags


def _balance(cells: set) -> set:
    """Split leaves until edge neighbours differ by at most one level (2:1)."""
    changed = True
    while changed:
        changed = False
        by_pos = {(c[0], c[1]): c for c in cells}
        to_split = set()
        for c in cells:
            x0, y0, s = c
            if s < 4:
                continue
            # a fine neighbour of size <= s/4 along any edge forces a split
            q = s // 4
            if q < 1:
                continue
            probes = []
            for t in range(0, s, q):
                probes += [(x0 - q, y0 + t), (x0 + s, y0 + t), (x0 + t, y0 - q), (x0 + t, y0 + s)]
            for p in probes:
                d = by_pos.get(p)
                if d is not None and d[2] <= q:
                    to_split.add(c)
                    break
        if to_split:
            changed = True
            for c in to_split:
                cells.discard(c)
                x0, y0, s = c
                h = s // 2
                for ch in ((x0, y0, h), (x0 + h, y0, h), (x0, y0 + h, h), (x0 + h, y0 + h, h)):
                    cells.add(ch)
    return cells


def refine_cells(base_cells: np.ndarray, flags_fn, ref: Refinement) -> np.ndarray:
    """Split flagged cells level by level, then 2:1-balance; returns leaves (x0, y0, size)."""
    cells = {tuple(int(v) for v in c) for c in base_cells}
    min_size = max(2, int(ref.min_size))
    for _ in range(max(1, int(ref.levels))):
        arr = np.array(sorted(cells), dtype=np.int64)
        can = (arr[:, 2] % 2 == 0) & (arr[:, 2] // 2 >= min_size)
        flags = flags_fn(arr) & can
        if not flags.any():
            break
        for c in arr[flags]:
            x0, y0, s = (int(v) for v in c)
            cells.discard((x0, y0, s))
            h = s // 2
            cells.update({(x0, y0, h), (x0 + h, y0, h), (x0, y0 + h, h), (x0 + h, y0 + h, h)})
    cells = _balance(cells)
    return np.array(sorted(cells), dtype=np.int64)


def build_quadtree(grid, roi: np.ndarray, ref: Refinement, half: int,
                   bad_nodes_xy: np.ndarray | None = None,
                   cells: np.ndarray | None = None) -> QuadMesh:
    """Refine the base mesh of ``grid`` by ``ref`` and return the new mesh.

    ``cells`` may give the current leaves (for a second, error-driven pass);
    by default the leaves are the lattice cells of ``grid``.
    """
    step = int(grid.xs[1] - grid.xs[0]) if grid.xs.size > 1 else int(grid.ys[1] - grid.ys[0])
    if cells is None:
        X0, Y0 = np.meshgrid(grid.xs[:-1], grid.ys[:-1])
        cells = np.column_stack([X0.ravel(), Y0.ravel(), np.full(X0.size, step)])
        # only cells whose four corners are nodes of the grid
        idx = grid.index_image()
        ok = ((idx[:-1, :-1] >= 0) & (idx[:-1, 1:] >= 0) & (idx[1:, :-1] >= 0)
              & (idx[1:, 1:] >= 0)).ravel()
        if ref.elements:
            manual = np.zeros(ok.size, bool)
            manual[np.asarray(ref.elements, np.int64)] = True
            manual = manual[ok]
        cells = cells[ok]
    else:
        manual = None
    base_manual = manual if (cells is not None and ref.elements and bad_nodes_xy is None) else None

    def flags_fn(arr):
        f = flag_elements(arr, roi, ref, half, bad_nodes_xy=bad_nodes_xy)
        if base_manual is not None and arr.shape[0] == base_manual.size:
            f |= base_manual
        return f

    leaves = refine_cells(cells, flags_fn, ref) if ref.any() else cells
    return _mesh_from_cells(grid, roi, leaves)


def _mesh_from_cells(grid, roi: np.ndarray, leaves: np.ndarray) -> QuadMesh:
    """Nodes, elements (inside the ROI) and hanging constraints of the leaves."""
    x0, y0, s = leaves[:, 0], leaves[:, 1], leaves[:, 2]
    corners = np.stack([np.column_stack([x0, y0]), np.column_stack([x0 + s, y0]),
                        np.column_stack([x0 + s, y0 + s]), np.column_stack([x0, y0 + s])], 1)
    # node set: lattice nodes in the ROI plus every leaf corner in the ROI
    pts = np.concatenate([np.column_stack([grid.x, grid.y]), corners.reshape(-1, 2)])
    h, w = roi.shape
    pts = pts[(pts[:, 0] >= 0) & (pts[:, 0] < w) & (pts[:, 1] >= 0) & (pts[:, 1] < h)]
    pts = pts[roi[pts[:, 1], pts[:, 0]]]
    # keep lattice nodes first, in grid order, so their indices match the grid
    key = pts[:, 1] * (w + 1) + pts[:, 0]
    _, first = np.unique(key, return_index=True)
    uniq = pts[np.sort(first)]
    gkey = grid.y * (w + 1) + grid.x
    ukey = uniq[:, 1] * (w + 1) + uniq[:, 0]
    extra = uniq[~np.isin(ukey, gkey)]
    nodes = np.concatenate([np.column_stack([grid.x, grid.y]), extra])
    nkey = nodes[:, 1] * (w + 1) + nodes[:, 0]
    order = np.argsort(nkey)
    lookup_keys = nkey[order]

    def find(xy):
        k = xy[..., 1] * (w + 1) + xy[..., 0]
        pos = np.searchsorted(lookup_keys, k)
        pos = np.clip(pos, 0, lookup_keys.size - 1)
        hit = lookup_keys[pos] == k
        return np.where(hit, order[pos], -1)

    el = find(corners)
    keep = (el >= 0).all(axis=1)
    x = nodes[:, 0].astype(np.float64)
    y = nodes[:, 1].astype(np.float64)
    e = el[keep]
    inside = element_inside_roi(x, y, e, roi)
    e = e[inside]
    kept_cells = leaves[keep][inside]
    # hanging nodes: the midpoint of a kept element's edge that is a corner of another element
    used = np.zeros(nodes.shape[0], bool)
    used[e.ravel()] = True
    hanging = []
    if e.shape[0]:
        hs = kept_cells[:, 2] // 2
        cx0, cy0, cs = kept_cells[:, 0], kept_cells[:, 1], kept_cells[:, 2]
        edges = [  # (midpoint, end a, end b) for the four edges
            ((cx0 + hs, cy0), 0, 1), ((cx0 + cs, cy0 + hs), 1, 2),
            ((cx0 + hs, cy0 + cs), 2, 3), ((cx0, cy0 + hs), 3, 0)]
        seen = set()
        for (mx, my), a, b in edges:
            mid = find(np.column_stack([mx, my]))
            ok = (mid >= 0) & (cs % 2 == 0)
            ok[ok] = used[mid[ok]]
            for k in np.nonzero(ok)[0]:
                hnode = int(mid[k])
                if hnode in seen:
                    continue
                seen.add(hnode)
                hanging.append((hnode, int(e[k, a]), int(e[k, b])))
    hang = np.array(hanging, dtype=np.int64).reshape(-1, 3)
    base_index = np.full(nodes.shape[0], -1, np.int64)
    base_index[:grid.n] = np.arange(grid.n)
    level = np.rint(np.log2(max(1, int(leaves[:, 2].max())) / kept_cells[:, 2])).astype(np.int64) \
        if kept_cells.size else np.zeros(0, np.int64)
    mesh = Q4Mesh(x, y, e.astype(np.int64), hang, level)
    return QuadMesh(mesh, base_index, kept_cells)
