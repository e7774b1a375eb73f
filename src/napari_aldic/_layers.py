"""DIC results as napari layer data: ``(data, kwargs, layer_type)`` tuples.

napari itself is not imported: the functions here return plain layer-data
tuples that the dock widget adds to (or updates in) the viewer and that the
reader returns for result files.

Layers made (a new run replaces the previous one; every layer names its
field in ``metadata["napari_aldic"]["field"]`` and its name carries the unit,
which also shows in the status bar when hovering):

* ``DIC u [px]``, ``DIC v [px]``, ``DIC |u| [px]`` and ``DIC exx [-]``,
  ``DIC eyy [-]``, ``DIC exy [-]``, ``DIC von Mises [-]``: Image layers on the
  node lattice (one pixel per node, pixel spacing = ``step`` image pixels; on
  a refined quadtree mesh a grid as fine as the smallest element, filled by the
  elements' bilinear interpolation), with the image's time axis so that the
  frame slider shows that frame's field; NaN (transparent) where a node is
  untrusted or outside the ROI. Colour limits come from the data (robust
  percentiles over all frames);
* ``DIC displacement [px]``: a Vectors layer at the trusted nodes, every node
  value (u, v, ZNCC, strains ...) in its ``features``;
* ``DIC unreliable nodes``: Points at the untrusted nodes, the reason in
  ``features``;
* ``DIC mesh``: the element outlines as a Shapes layer (optional).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from .engine import DICResult, Reason
from .engine.io import result_cells
from .engine.viz import colour_limits, fine_grid, on_fine_grid, rigid_motion, to_deformed
from .i18n import tr

__all__ = ["Geometry", "Display", "DISPLAY_FIELDS", "RESULT_KEYS", "REASON_COLORS",
           "layer_name", "is_result_name", "analysis_layers", "field_on_lattice"]

PREFIX = "DIC "

#: the result fields shown as Image layers: key (the layer name after "DIC ") ->
#: (attribute, quantity, colormap, colour limits, description)
DISPLAY_FIELDS = {
    "u": ("u", "length", "turbo", "range", "displacement along x (columns)"),
    "v": ("v", "length", "turbo", "range", "displacement along y (rows, down)"),
    "|u|": ("magnitude", "length", "viridis", "from_zero", "displacement magnitude"),
    "exx": ("exx", "strain", "RdBu_r", "symmetric", "normal strain along x"),
    "eyy": ("eyy", "strain", "RdBu_r", "symmetric", "normal strain along y"),
    "exy": ("exy", "strain", "PuOr_r", "symmetric", "tensor shear strain"),
    "von Mises": ("von_mises", "strain", "magma", "from_zero",
                  "equivalent (von Mises) strain"),
}
VECTORS = "displacement"
UNRELIABLE = "unreliable nodes"
MESH = "mesh"
RESULT_KEYS = (*DISPLAY_FIELDS, VECTORS, UNRELIABLE, MESH)
_NAME = re.compile(r"^DIC (.+?)( \[[^\]]*\])?$")

#: colour of each flagged reason code in the unreliable-nodes layer (RGBA), from the
#: engine's one reason table (the figures use the same colours)
REASON_COLORS = {int(code): tuple(int(Reason.colour(code)[i:i + 2], 16) / 255
                                  for i in (1, 3, 5)) + (1.0,)
                 for code in Reason if code != Reason.OK}


def layer_name(key: str, unit: str | None = None) -> str:
    """The viewer name of result layer ``key`` with its unit (e.g. ``"u"``,
    ``"µm"`` -> ``"DIC u [µm]"``)."""
    return PREFIX + key + (f" [{unit}]" if unit else "")


#: mantissas of a limit that napari's colour bar (vispy's tick finder, at its
#: 150 px height) labels: with these, its ticks read -a, 0, +a (or 0, a)
_BAR_MANTISSAS = (1.0, 2.0, 3.0, 4.0, 5.0, 10.0)


def bar_limits(clim: tuple[float, float]) -> tuple[float, float]:
    """Colour limits ``(-a, a)`` or ``(0, a)`` with ``a`` rounded up to a value the
    canvas colour bar puts a tick on (otherwise ``±0.8`` is labelled "0" only);
    other limits are returned as they are."""
    lo, hi = (float(c) for c in clim)
    if hi <= 0 or not (lo == 0 or np.isclose(lo, -hi, rtol=1e-9)):
        return lo, hi
    exp = 10.0 ** np.floor(np.log10(hi))
    a = next(m * exp for m in _BAR_MANTISSAS if m * exp >= hi * (1 - 1e-9))
    return (0.0 if lo == 0 else -a), a


def is_result_name(name: str) -> bool:
    """Whether ``name`` is the name of a result layer (any unit)."""
    m = _NAME.match(name)
    return bool(m) and m.group(1) in RESULT_KEYS


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

    def last(self, n: int) -> Geometry:
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

    fields: tuple = tuple(DISPLAY_FIELDS)
    visible_field: str = "|u|"
    vectors: bool = True
    vector_length: float = 0.0  # arrow length per unit displacement; 0 = automatic
    unreliable: bool = True
    mesh: bool = False
    deformed: bool = False
    rigid: bool = False  # subtract each frame's rigid-body motion from u, v, |u|
    length_scale: float = 1.0  # physical length of one pixel
    length_unit: str = "px"
    frame_interval: float | None = None  # None: frame numbers only
    time_unit: str = "s"

    def unit_of(self, key: str) -> str:
        """The unit shown for result ``key``: the length unit, or ``-`` for strains."""
        if key == VECTORS or (key in DISPLAY_FIELDS and DISPLAY_FIELDS[key][1] == "length"):
            return self.length_unit
        return "-" if key in DISPLAY_FIELDS else ""


# ----------------------------------------------------------------- helpers
def _displacement(res: DICResult, display: Display) -> tuple[np.ndarray, np.ndarray]:
    """u, v of ``res`` in pixels, without the rigid-body motion when asked."""
    u, v = np.asarray(res.u, float), np.asarray(res.v, float)
    if display.rigid:
        ur, vr = rigid_motion(res.x, res.y, u, v, res.valid)
        u, v = u - ur, v - vr
    return u, v


def _node_values(res: DICResult, strain, key: str, display: Display) -> np.ndarray:
    attr = DISPLAY_FIELDS[key][0]
    if attr in ("u", "v", "magnitude"):
        u, v = _displacement(res, display)
        return {"u": u, "v": v, "magnitude": np.hypot(u, v)}[attr]
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


def _frame_coords(t, y, x, with_time: bool) -> np.ndarray:
    if with_time:
        return np.column_stack([np.full(y.size, float(t)), y, x])
    return np.column_stack([y, x])


@dataclass(frozen=True)
class _Grid:
    """Where the field images are drawn: the node lattice, or the finer grid of a
    refined mesh (``pitch`` < step)."""

    pitch: float
    origin: tuple  # (x0, y0) pixels
    shape: tuple  # (rows, cols)
    fine: bool

    @classmethod
    def of(cls, analysis) -> _Grid:
        done = [r for r in analysis.results if r is not None]
        base = done[0]
        if not any(np.any(np.asarray(r.grid_ix) < 0) for r in done):
            step = float(base.params.step)
            return cls(step, (float(base.grid_xs[0]), float(base.grid_ys[0])),
                       base.grid_shape, False)
        pitch, origin, shape = fine_grid(done)
        return cls(pitch, origin, shape, True)

    def put(self, res: DICResult, values: np.ndarray) -> np.ndarray:
        """Trusted node values of ``res`` on this grid (NaN elsewhere)."""
        if not self.fine:
            return field_on_lattice(res, values)
        masked = np.where(np.asarray(res.valid, bool), np.asarray(values, float), np.nan)
        return on_fine_grid(res, masked, self.pitch, self.origin, self.shape)


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
        raise ValueError(tr("the image has {ndim} axes; a stack has (time, rows, cols)").format(
                                ndim=geo.ndim))
    meta = _common_meta(analysis, base, display)
    layers = _image_layers(analysis, geo, display, meta)
    tables = _node_tables(analysis, display, with_time)
    if display.vectors:
        layers.append(_vectors_layer(analysis, tables, geo, display, meta))
    if display.unreliable:
        layers.append(_unreliable_layer(tables, geo, display, meta, float(base.params.step)))
    if display.mesh:
        layers.append(_mesh_layer(analysis, geo, display, with_time, meta))
    return layers


def _common_meta(analysis, base: DICResult, display: Display) -> dict:
    """Metadata every result layer carries under ``"napari_aldic"``."""
    return {"frames": list(analysis.frames), "length_unit": display.length_unit,
            "pixel_size": float(display.length_scale),
            "frame_interval": display.frame_interval, "time_unit": display.time_unit,
            "params": base.params.to_dict(), "reference": analysis.reference,
            "cancelled": analysis.cancelled, "rigid_removed": display.rigid,
            "strain": {"window": analysis.strain.window, "method": analysis.strain.method,
                       "measure": analysis.strain.measure}}


def _field_stacks(analysis, display: Display, grid: _Grid) -> dict[str, np.ndarray]:
    """Every displayed field on ``grid``, one plane per frame of the image's time
    axis (or one plane without a time axis: the last frame)."""
    with_time = analysis.n_frames is not None
    shape = grid.shape if not with_time else (analysis.n_frames, *grid.shape)
    stacks = {k: np.full(shape, np.nan, np.float32) for k in display.fields}
    for i, res in enumerate(analysis.results):
        if res is None:
            continue
        strain = analysis.strains[i] if i < len(analysis.strains) else None
        grids = []
        for k in display.fields:
            vals = _node_values(res, strain, k, display)
            if DISPLAY_FIELDS[k][1] == "length":
                vals = vals * float(display.length_scale)
            grids.append(grid.put(res, vals))
        if display.deformed and i > 0:
            grids = to_deformed(grids, grid.put(res, res.u), grid.put(res, res.v), grid.pitch)
        for k, g in zip(display.fields, grids):
            if with_time:
                stacks[k][analysis.frames[i]] = g
            else:
                stacks[k][...] = g  # no time axis: the last computed frame
    return stacks


def _moving_frames(analysis) -> list | None:
    """The planes of the time axis whose fields set the colour limits: every
    computed frame but the reference (a zero field) when there is one; ``None``:
    no time axis."""
    if analysis.n_frames is None:
        return None
    done = [k for k, r in zip(analysis.frames, analysis.results) if r is not None]
    return done[1:] if len(done) > 1 else done


def _image_layers(analysis, geo: Geometry, display: Display, meta: dict) -> list:
    """One Image layer per displayed field, on the node lattice (one pixel per
    node, pixel spacing = ``step`` image pixels) or the finer grid of a refined mesh."""
    grid = _Grid.of(analysis)
    sy, sx = geo.scale[-2:]
    ty, tx = geo.translate[-2:]
    lat = geo.kwargs()
    lat["scale"] = (*lat["scale"][:-2], grid.pitch * sy, grid.pitch * sx)
    lat["translate"] = (*lat["translate"][:-2], ty + grid.origin[1] * sy,
                        tx + grid.origin[0] * sx)
    layers = []
    moving = _moving_frames(analysis)
    for k, data in _field_stacks(analysis, display, grid).items():
        _, quantity, cmap, limits, desc = DISPLAY_FIELDS[k]
        if quantity == "length":
            u_txt = display.length_unit
        else:
            u_txt = f"{analysis.strain.measure.replace('_', '-')} strain (dimensionless)"
        clim = bar_limits(colour_limits(data[moving] if moving is not None else data, limits))
        layers.append((data, {
            "name": layer_name(k, display.unit_of(k)), **lat, "colormap": cmap,
            "contrast_limits": clim, "interpolation2d": "nearest",
            "blending": "translucent", "opacity": 0.8, "visible": k == display.visible_field,
            "metadata": {"napari_aldic": {**meta, "field": k, "description": desc,
                                          "value_unit": u_txt, "deformed": display.deformed,
                                          "auto_colormap": cmap, "auto_limits": clim,
                                          "grid_pitch_px": grid.pitch},
                         "napari_aldic_analysis": analysis},
        }, "image"))
    return layers


@dataclass
class _NodeTables:
    """Per-frame node positions and features: trusted nodes (vectors) and
    untrusted ones (unreliable-node points)."""

    vec_rows: list
    vec_feats: list
    bad_rows: list
    bad_feats: list
    ndim: int


def _trusted_rows(res: DICResult, strain, t, display: Display, with_time: bool):
    """(vector rows, features) of the trusted nodes of one frame; the arrows and
    values lose the rigid-body motion when the display asks for it (the nodes
    stay where the material is)."""
    L = float(display.length_scale)
    ok = np.asarray(res.valid, bool) & np.isfinite(res.u) & np.isfinite(res.v)
    x, y = res.x[ok].astype(float), res.y[ok].astype(float)
    if display.deformed:
        x, y = x + res.u[ok], y + res.v[ok]
    du, dv = (a[ok] for a in _displacement(res, display))
    pos = _frame_coords(t, y, x, with_time)
    proj = _frame_coords(0.0, dv, du, with_time)
    feats = {"frame": np.full(ok.sum(), t, np.int64), "x_px": res.x[ok].astype(float),
             "y_px": res.y[ok].astype(float), "u": du * L, "v": dv * L,
             "magnitude": np.hypot(du, dv) * L,
             "zncc": np.asarray(res.zncc, float)[ok]}
    for name in ("exx", "eyy", "exy", "von_mises"):
        feats[name] = (np.asarray(getattr(strain, name), float)[ok] if strain is not None
                       else np.full(ok.sum(), np.nan))
    return np.stack([pos, proj], axis=1), feats


def _untrusted_rows(res: DICResult, t, display: Display, with_time: bool):
    """(point rows, features) of the untrusted nodes of one frame."""
    bad = ~np.asarray(res.valid, bool) & np.isfinite(res.x) & np.isfinite(res.y)
    bx, by = res.x[bad].astype(float), res.y[bad].astype(float)
    if display.deformed:
        shift = np.isfinite(res.u[bad]) & np.isfinite(res.v[bad])
        bx = np.where(shift, bx + np.nan_to_num(res.u[bad]), bx)
        by = np.where(shift, by + np.nan_to_num(res.v[bad]), by)
    codes = np.asarray(res.reason, np.int64)[bad]
    feats = {"frame": np.full(bad.sum(), t, np.int64),
             "x_px": res.x[bad].astype(float), "y_px": res.y[bad].astype(float),
             "reason": codes,
             "reason_text": np.array([Reason.describe(c) for c in codes], object),
             "zncc": np.asarray(res.zncc, float)[bad]}
    return _frame_coords(t, by, bx, with_time), feats


def _node_tables(analysis, display: Display, with_time: bool) -> _NodeTables:
    tables = _NodeTables([], [], [], [], 3 if with_time else 2)
    for i, res in enumerate(analysis.results):
        if res is None:
            continue
        t = analysis.frames[i]
        strain = analysis.strains[i] if i < len(analysis.strains) else None
        rows, feats = _trusted_rows(res, strain, t, display, with_time)
        tables.vec_rows.append(rows)
        tables.vec_feats.append(feats)
        rows, feats = _untrusted_rows(res, t, display, with_time)
        tables.bad_rows.append(rows)
        tables.bad_feats.append(feats)
    return tables


def _concat(parts: list, empty_shape) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(empty_shape)


def _concat_features(parts: list, keys) -> dict:
    return {k: np.concatenate([p[k] for p in parts]) if parts else np.zeros(0) for k in keys}


def _vectors_layer(analysis, tables: _NodeTables, geo: Geometry, display: Display,
                   meta: dict):
    """The displacement arrows at the trusted nodes, every node value in the features."""
    step = float(analysis.lattice().params.step)
    vdata = _concat(tables.vec_rows, (0, 2, tables.ndim))
    length = float(display.vector_length)
    if length <= 0:  # automatic: the longest arrows (95th percentile) span ~one node step
        mags = np.hypot(vdata[:, 1, -1], vdata[:, 1, -2]) if len(vdata) else np.zeros(0)
        big = float(np.percentile(mags, 95)) if mags.size else 0.0
        length = 0.9 * step / big if big > 1e-9 else 1.0
    keys = ("frame", "x_px", "y_px", "u", "v", "magnitude", "zncc", "exx", "eyy", "exy",
            "von_mises")
    kw = {"name": layer_name(VECTORS, display.length_unit), **geo.kwargs(),
          "features": _concat_features(tables.vec_feats, keys),
          "length": length, "edge_width": max(1.0, step / 6.0),
          "vector_style": "arrow", "projection_mode": "none", "opacity": 0.9,
          "metadata": {"napari_aldic": {**meta, "field": VECTORS,
                                        "value_unit": display.length_unit,
                                        "deformed": display.deformed},
                       "napari_aldic_analysis": analysis}}
    if len(vdata):
        kw.update(edge_color="magnitude", edge_colormap="viridis")
    else:
        kw["edge_color"] = "white"
    return vdata, kw, "vectors"


def _unreliable_layer(tables: _NodeTables, geo: Geometry, display: Display, meta: dict,
                      step: float):
    """Points at the untrusted nodes, coloured by the reason (in the features)."""
    pdata = _concat(tables.bad_rows, (0, tables.ndim))
    feats = _concat_features(tables.bad_feats,
                             ("frame", "x_px", "y_px", "reason", "reason_text", "zncc"))
    colors = np.array([REASON_COLORS.get(int(c), (1, 0, 0, 1)) for c in feats["reason"]]
                      ).reshape(-1, 4) if len(pdata) else "red"
    return (pdata, {
        "name": layer_name(UNRELIABLE), **geo.kwargs(), "features": feats,
        "size": max(2.0, 0.5 * step), "symbol": "x", "face_color": colors,
        "border_width": 0.0, "projection_mode": "none", "opacity": 0.9,
        "metadata": {"napari_aldic": {**meta, "field": UNRELIABLE,
                                      "deformed": display.deformed,
                                      "reasons": {int(c): Reason.describe(c)
                                                  for c in Reason}}},
    }, "points")


def _edge_chains(res: DICResult) -> list[np.ndarray]:
    """The element edges of ``res`` joined into polylines of node indices.

    Edges are axis-aligned in the reference configuration; collinear edges
    that share a node are chained, so a uniform mesh becomes one line per
    lattice row and column segment (a few dozen Shapes instead of thousands).
    """
    el = result_cells(res)
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
