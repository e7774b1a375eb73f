"""DIC results as napari layer data: ``(data, kwargs, layer_type)`` tuples.

napari itself is not imported: the functions here return plain layer-data
tuples that the dock widget adds to (or updates in) the viewer and that the
reader returns for result files.

Layers made (names are fixed, so a new run replaces the previous one):

* ``DIC u``, ``DIC v``, ``DIC |u|`` and ``DIC exx``, ``DIC eyy``, ``DIC exy``,
  ``DIC von Mises``: Image layers on the node lattice (one pixel per node,
  pixel spacing = ``step`` image pixels), with the image's time axis so that
  the frame slider shows that frame's field; NaN (transparent) where a node is
  untrusted or outside the ROI;
* ``DIC displacement``: a Vectors layer at the trusted nodes, every node
  value (u, v, ZNCC, strains ...) in its ``features``;
* ``DIC unreliable nodes``: Points at the untrusted nodes, the reason in
  ``features``;
* ``DIC mesh``: the element outlines as a Shapes layer (optional).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .engine import DICResult, Reason

__all__ = ["Geometry", "Display", "FIELDS", "LAYER_NAMES", "layer_name", "analysis_layers",
           "field_on_lattice", "to_deformed"]

PREFIX = "DIC "

#: image fields: key -> (attribute, quantity, colormap, symmetric limits, description)
FIELDS = {
    "u": ("u", "length", "RdBu_r", True, "displacement along x (columns)"),
    "v": ("v", "length", "RdBu_r", True, "displacement along y (rows, down)"),
    "|u|": ("magnitude", "length", "viridis", False, "displacement magnitude"),
    "exx": ("exx", "strain", "RdBu_r", True, "normal strain along x"),
    "eyy": ("eyy", "strain", "RdBu_r", True, "normal strain along y"),
    "exy": ("exy", "strain", "PuOr_r", True, "tensor shear strain"),
    "von Mises": ("von_mises", "strain", "magma", False, "equivalent (von Mises) strain"),
}
VECTORS = "displacement"
UNRELIABLE = "unreliable nodes"
MESH = "mesh"
LAYER_NAMES = tuple(PREFIX + k for k in (*FIELDS, VECTORS, UNRELIABLE, MESH))

#: colour of each reason code in the unreliable-nodes layer (RGBA)
_REASON_COLORS = {
    int(Reason.SMALL_COMPONENT): (0.6, 0.6, 0.6, 1.0),
    int(Reason.NOT_CONVERGED): (1.0, 0.6, 0.0, 1.0),
    int(Reason.OUT_OF_IMAGE): (0.5, 0.3, 1.0, 1.0),
    int(Reason.LOW_CORRELATION): (1.0, 0.0, 0.0, 1.0),
    int(Reason.NO_TEXTURE): (0.0, 0.8, 0.8, 1.0),
    int(Reason.DIVERGED): (1.0, 0.0, 1.0, 1.0),
    int(Reason.NO_INITIAL_GUESS): (1.0, 1.0, 0.0, 1.0),
    int(Reason.OUTLIER): (1.0, 0.4, 0.7, 1.0),
}


def layer_name(key: str) -> str:
    """The viewer name of result layer ``key`` (e.g. ``"u"`` -> ``"DIC u"``)."""
    return PREFIX + key


@dataclass(frozen=True)
class Geometry:
    """World transform of the analysed image: one entry per image axis.

    For a stack the first axis is time. Result layers copy it so they sit
    exactly on the image, whatever its scale, offset and units.
    """

    scale: tuple = (1.0, 1.0)
    translate: tuple = (0.0, 0.0)
    units: tuple | None = None
    axis_labels: tuple | None = None

    @property
    def ndim(self) -> int:
        return len(self.scale)

    def last(self, n: int) -> "Geometry":
        """The transform of the last ``n`` axes."""
        return Geometry(tuple(self.scale[-n:]), tuple(self.translate[-n:]),
                        None if self.units is None else tuple(self.units[-n:]),
                        None if self.axis_labels is None else tuple(self.axis_labels[-n:]))

    def kwargs(self) -> dict:
        kw = {"scale": tuple(float(s) for s in self.scale),
              "translate": tuple(float(t) for t in self.translate)}
        if self.units is not None:
            kw["units"] = tuple(str(u) for u in self.units)
        if self.axis_labels is not None:
            kw["axis_labels"] = tuple(str(a) for a in self.axis_labels)
        return kw


@dataclass(frozen=True)
class Display:
    """Which result layers to make and how."""

    fields: tuple = tuple(FIELDS)
    visible_field: str = "|u|"
    vectors: bool = True
    vector_length: float = 0.0  # arrow length per unit displacement; 0 = automatic
    unreliable: bool = True
    mesh: bool = False
    deformed: bool = False
    length_scale: float = 1.0  # physical length of one pixel
    length_unit: str = "px"
    frame_interval: float | None = None  # None: frame numbers only
    time_unit: str = "s"


# ----------------------------------------------------------------- helpers
def _node_values(res: DICResult, strain, key: str) -> np.ndarray:
    attr = FIELDS[key][0]
    if attr == "magnitude":
        return np.hypot(res.u, res.v)
    if attr in ("u", "v"):
        return np.asarray(getattr(res, attr), float)
    if strain is None:
        return np.full(len(res), np.nan)
    return np.where(strain.valid, np.asarray(getattr(strain, attr), float), np.nan)


def field_on_lattice(res: DICResult, values: np.ndarray, valid: np.ndarray | None = None
                     ) -> np.ndarray:
    """Node values on the result's lattice (rows = y), NaN where untrusted or
    off-lattice (quadtree nodes between lattice points are skipped)."""
    out = np.full(res.grid_shape, np.nan)
    ok = (res.grid_ix >= 0) & np.asarray(res.valid, bool)
    if valid is not None:
        ok &= valid
    out[res.grid_iy[ok], res.grid_ix[ok]] = np.asarray(values, float)[ok]
    return out


def _fill_nearest(a: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    bad = ~np.isfinite(a)
    if not bad.any() or bad.all():
        return np.where(bad, 0.0, a)
    idx = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
    return a[tuple(idx)]


def to_deformed(grids: list[np.ndarray], u: np.ndarray, v: np.ndarray, step: float,
                iterations: int = 12) -> list[np.ndarray]:
    """Lattice fields moved to the deformed configuration.

    ``u``, ``v`` (pixels) and every grid in ``grids`` live on the node lattice
    of the reference image (spacing ``step`` pixels). The value shown at the
    lattice point ``x`` is that of the material point ``X`` with
    ``X + u(X) = x``, found by fixed-point iteration ``X <- x - u(X)`` with
    bilinear interpolation; points no trusted material reaches are NaN.
    """
    from scipy import ndimage

    ok = np.isfinite(u) & np.isfinite(v)
    if not ok.any():
        return [np.full_like(g, np.nan) for g in grids]
    uf, vf = _fill_nearest(u) / step, _fill_nearest(v) / step  # lattice units
    rr, cc = np.mgrid[0:u.shape[0], 0:u.shape[1]].astype(float)
    R, C = rr.copy(), cc.copy()
    for _ in range(iterations):
        du = ndimage.map_coordinates(uf, [R, C], order=1, mode="nearest")
        dv = ndimage.map_coordinates(vf, [R, C], order=1, mode="nearest")
        R, C = rr - dv, cc - du
    inside = ndimage.map_coordinates(ok.astype(float), [R, C], order=0, mode="constant",
                                     cval=0.0) > 0.5
    out = []
    for g in grids:
        val = ndimage.map_coordinates(_fill_nearest(g), [R, C], order=1, mode="nearest")
        val[~inside | ~np.isfinite(ndimage.map_coordinates(
            np.where(np.isfinite(g), 0.0, np.nan), [R, C], order=0, mode="nearest"))] = np.nan
        out.append(val)
    return out


def _limits(stack: np.ndarray, symmetric: bool) -> tuple[float, float]:
    finite = stack[np.isfinite(stack)]
    if finite.size == 0:
        return (-1.0, 1.0) if symmetric else (0.0, 1.0)
    if symmetric:
        m = float(np.percentile(np.abs(finite), 99.5))
        m = m if m > 0 else max(float(np.abs(finite).max()), 1e-9)
        return (-m, m)
    lo, hi = 0.0, float(np.percentile(finite, 99.5))
    return (lo, hi if hi > lo else lo + max(float(finite.max()), 1e-9))


def _lattice_elements(res: DICResult) -> np.ndarray:
    """(E, 4) node indices of the quads of the result's mesh (or lattice)."""
    if res.elements is not None and len(res.elements):
        return np.asarray(res.elements, np.int64)
    idx = -np.ones(res.grid_shape, np.int64)
    on = res.grid_ix >= 0
    idx[res.grid_iy[on], res.grid_ix[on]] = np.nonzero(on)[0]
    a, b = idx[:-1, :-1], idx[:-1, 1:]
    c, d = idx[1:, 1:], idx[1:, :-1]
    quad = np.stack([a, b, c, d], -1).reshape(-1, 4)
    return quad[(quad >= 0).all(axis=1)]


def _frame_coords(t, y, x, with_time: bool) -> np.ndarray:
    if with_time:
        return np.column_stack([np.full(y.size, float(t)), y, x])
    return np.column_stack([y, x])


# ----------------------------------------------------------------- main entry
def analysis_layers(analysis, geometry: Geometry, display: Display = Display()) -> list:
    """Layer-data tuples for every result layer of ``analysis``.

    Parameters
    ----------
    analysis : napari_aldic._analysis.Analysis
    geometry : Geometry
        Transform of the analysed image (with its time axis when
        ``analysis.n_frames`` is not None).
    display : Display
    """
    base = analysis.lattice()
    if base is None:
        return []
    with_time = analysis.n_frames is not None
    geo = geometry if with_time else geometry.last(2)
    if with_time and geo.ndim != 3:
        raise ValueError(f"the image has {geo.ndim} axes; a stack has (time, rows, cols)")
    step = float(base.params.step)
    L, unit = float(display.length_scale), display.length_unit
    sy, sx = geo.scale[-2:]
    ty, tx = geo.translate[-2:]
    meta_common = {"frames": list(analysis.frames), "length_unit": unit,
                   "pixel_size": L, "frame_interval": display.frame_interval,
                   "time_unit": display.time_unit, "params": base.params.to_dict(),
                   "reference": analysis.reference, "cancelled": analysis.cancelled,
                   "strain": {"window": analysis.strain.window,
                              "method": analysis.strain.method,
                              "measure": analysis.strain.measure}}
    layers = []

    # --- lattice images
    lat_scale = (step * sy, step * sx)
    lat_translate = (ty + float(base.grid_ys[0]) * sy, tx + float(base.grid_xs[0]) * sx)
    lat = geo.kwargs()
    lat["scale"] = (*lat["scale"][:-2], *lat_scale)
    lat["translate"] = (*lat["translate"][:-2], *lat_translate)
    shape = base.grid_shape if not with_time else (analysis.n_frames, *base.grid_shape)
    stacks = {k: np.full(shape, np.nan, np.float32) for k in display.fields}
    for i, res in enumerate(analysis.results):
        if res is None:
            continue
        strain = analysis.strains[i] if i < len(analysis.strains) else None
        grids = []
        for k in display.fields:
            vals = _node_values(res, strain, k)
            if FIELDS[k][1] == "length":
                vals = vals * L
            grids.append(field_on_lattice(res, vals))
        if display.deformed and i > 0:
            grids = to_deformed(grids, field_on_lattice(res, res.u),
                                field_on_lattice(res, res.v), step)
        for k, g in zip(display.fields, grids):
            if with_time:
                stacks[k][analysis.frames[i]] = g
            else:
                stacks[k][...] = g  # no time axis: the last computed frame
    for k in display.fields:
        attr, quantity, cmap, sym, desc = FIELDS[k]
        data = stacks[k]
        u_txt = unit if quantity == "length" else "strain (dimensionless)"
        if quantity == "strain":
            u_txt = f"{analysis.strain.measure.replace('_', '-')} strain (dimensionless)"
        layers.append((data, {
            "name": layer_name(k), **lat, "colormap": cmap,
            "contrast_limits": _limits(data, sym), "interpolation2d": "nearest",
            "blending": "translucent", "opacity": 0.8, "visible": k == display.visible_field,
            "metadata": {"napari_aldic": {**meta_common, "field": k, "description": desc,
                                          "value_unit": u_txt, "deformed": display.deformed},
                         "napari_aldic_analysis": analysis},
        }, "image"))

    # --- per-node tables: vectors at trusted nodes, points at untrusted ones
    vec_rows, vec_feats, bad_rows, bad_feats = [], [], [], []
    for i, res in enumerate(analysis.results):
        if res is None:
            continue
        t = analysis.frames[i]
        strain = analysis.strains[i] if i < len(analysis.strains) else None
        ok = np.asarray(res.valid, bool) & np.isfinite(res.u) & np.isfinite(res.v)
        x, y = res.x[ok].astype(float), res.y[ok].astype(float)
        if display.deformed:
            x, y = x + res.u[ok], y + res.v[ok]
        pos = _frame_coords(t, y, x, with_time)
        proj = _frame_coords(0.0, res.v[ok], res.u[ok], with_time)
        vec_rows.append(np.stack([pos, proj], axis=1))
        feats = {"frame": np.full(ok.sum(), t, np.int64), "x_px": res.x[ok].astype(float),
                 "y_px": res.y[ok].astype(float), "u": res.u[ok] * L, "v": res.v[ok] * L,
                 "magnitude": np.hypot(res.u[ok], res.v[ok]) * L,
                 "zncc": np.asarray(res.zncc, float)[ok]}
        for name in ("exx", "eyy", "exy", "von_mises"):
            feats[name] = (np.asarray(getattr(strain, name), float)[ok] if strain is not None
                           else np.full(ok.sum(), np.nan))
        vec_feats.append(feats)

        bad = ~np.asarray(res.valid, bool) & np.isfinite(res.x) & np.isfinite(res.y)
        bx, by = res.x[bad].astype(float), res.y[bad].astype(float)
        if display.deformed:
            shift = np.isfinite(res.u[bad]) & np.isfinite(res.v[bad])
            bx = np.where(shift, bx + np.nan_to_num(res.u[bad]), bx)
            by = np.where(shift, by + np.nan_to_num(res.v[bad]), by)
        bad_rows.append(_frame_coords(t, by, bx, with_time))
        codes = np.asarray(res.reason, np.int64)[bad]
        bad_feats.append({"frame": np.full(bad.sum(), t, np.int64),
                          "x_px": res.x[bad].astype(float), "y_px": res.y[bad].astype(float),
                          "reason": codes,
                          "reason_text": np.array([Reason.describe(c) for c in codes], object),
                          "zncc": np.asarray(res.zncc, float)[bad]})
    ndim = 3 if with_time else 2
    node_geo = geo.kwargs()

    def cat(parts, empty_shape):
        return np.concatenate(parts) if parts else np.zeros(empty_shape)

    def cat_feats(parts, keys):
        return {k: np.concatenate([p[k] for p in parts]) if parts else np.zeros(0)
                for k in keys}

    if display.vectors:
        vdata = cat(vec_rows, (0, 2, ndim))
        length = float(display.vector_length)
        if length <= 0:  # automatic: the longest arrows (95th percentile) span ~one node step
            mags = np.hypot(vdata[:, 1, -1], vdata[:, 1, -2]) if len(vdata) else np.zeros(0)
            big = float(np.percentile(mags, 95)) if mags.size else 0.0
            length = 0.9 * step / big if big > 1e-9 else 1.0
        keys = ("frame", "x_px", "y_px", "u", "v", "magnitude", "zncc", "exx", "eyy", "exy",
                "von_mises")
        feats = cat_feats(vec_feats, keys)
        kw = {"name": layer_name(VECTORS), **node_geo, "features": feats,
              "length": length, "edge_width": max(1.0, step / 6.0),
              "vector_style": "arrow", "projection_mode": "none", "opacity": 0.9,
              "metadata": {"napari_aldic": {**meta_common, "field": VECTORS,
                                            "value_unit": unit,
                                            "deformed": display.deformed},
                           "napari_aldic_analysis": analysis}}
        if len(vdata):
            kw.update(edge_color="magnitude", edge_colormap="viridis")
        else:
            kw["edge_color"] = "white"
        layers.append((vdata, kw, "vectors"))

    if display.unreliable:
        pdata = cat(bad_rows, (0, ndim))
        keys = ("frame", "x_px", "y_px", "reason", "reason_text", "zncc")
        feats = cat_feats(bad_feats, keys)
        colors = np.array([_REASON_COLORS.get(int(c), (1, 0, 0, 1)) for c in feats["reason"]]
                          ).reshape(-1, 4) if len(pdata) else "red"
        layers.append((pdata, {
            "name": layer_name(UNRELIABLE), **node_geo, "features": feats,
            "size": max(2.0, 0.5 * step), "symbol": "x", "face_color": colors,
            "border_width": 0.0, "projection_mode": "none", "opacity": 0.9,
            "metadata": {"napari_aldic": {**meta_common, "field": UNRELIABLE,
                                          "deformed": display.deformed,
                                          "reasons": {int(c): Reason.describe(c)
                                                      for c in Reason}}},
        }, "points"))

    if display.mesh:
        layers.append(_mesh_layer(analysis, geo, display, with_time, meta_common))
    return layers


def _edge_chains(res: DICResult) -> list[np.ndarray]:
    """The element edges of ``res`` joined into polylines of node indices.

    Edges are axis-aligned in the reference configuration; collinear edges
    that share a node are chained, so a uniform mesh becomes one line per
    lattice row and column segment (a few dozen Shapes instead of thousands).
    """
    el = _lattice_elements(res)
    if el.size == 0:
        return []
    pairs = np.concatenate([el[:, [0, 1]], el[:, [1, 2]], el[:, [2, 3]], el[:, [3, 0]]])
    pairs = np.unique(np.sort(pairs, axis=1), axis=0)
    x, y = res.x.astype(float), res.y.astype(float)
    chains = []
    for along, across in ((x, y), (y, x)):  # horizontal edges, then vertical ones
        sel = pairs[across[pairs[:, 0]] == across[pairs[:, 1]]]
        if sel.size == 0:
            continue
        # orient each edge in increasing coordinate, sort by line then start
        swap = along[sel[:, 0]] > along[sel[:, 1]]
        sel[swap] = sel[swap][:, ::-1]
        order = np.lexsort((along[sel[:, 0]], across[sel[:, 0]]))
        sel = sel[order]
        current = [int(sel[0, 0]), int(sel[0, 1])]
        for a, b in sel[1:]:
            if a == current[-1]:
                current.append(int(b))
            else:
                chains.append(np.asarray(current))
                current = [int(a), int(b)]
        chains.append(np.asarray(current))
    return chains


def _mesh_layer(analysis, geo: Geometry, display: Display, with_time: bool, meta: dict):
    """Element outlines as paths (edges chained into lines).

    Undeformed: the reference mesh, without a time axis (shown on every
    frame). Deformed: the mesh of each computed frame moved by its field, on
    that frame.
    """
    paths = []
    if not display.deformed:
        res = [r for r in analysis.results if r is not None][-1]
        yx = np.column_stack([res.y, res.x]).astype(float)
        paths = [yx[c] for c in _edge_chains(res)]
        kw_geo = geo.last(2).kwargs()
    else:
        for i, res in enumerate(analysis.results):
            if res is None:
                continue
            fin = np.isfinite(res.u) & np.isfinite(res.v)
            y = res.y + np.where(fin, res.v, 0.0)
            x = res.x + np.where(fin, res.u, 0.0)
            pts = (np.column_stack([np.full(x.size, float(analysis.frames[i])), y, x])
                   if with_time else np.column_stack([y, x]))
            for c in _edge_chains(res):
                # split a chain where a node has no displacement
                ok = fin[c]
                runs = np.split(c, np.nonzero(np.diff(ok.astype(np.int8)))[0] + 1)
                paths.extend(pts[r] for r in runs if len(r) > 1 and fin[r].all())
        kw_geo = geo.kwargs()
    return (paths, {"name": layer_name(MESH), **kw_geo, "shape_type": "path",
                    "edge_color": "white", "edge_width": 0.5, "opacity": 0.6,
                    "metadata": {"napari_aldic": {**meta, "field": MESH,
                                                  "deformed": display.deformed,
                                                  "lines": len(paths)}}}, "shapes")
