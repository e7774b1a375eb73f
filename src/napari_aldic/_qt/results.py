"""Result layers in the viewer: add, update in place or replace them (no Qt here).

:class:`ResultLayers` holds the last analysis and the image it was computed
on, and turns them into the viewer's ``DIC ...`` layers with
:func:`napari_aldic._layers.analysis_layers`. The layer data can be made in a
worker thread (:meth:`ResultLayers.prepare`); putting them in the viewer is a
sequence of small steps (:meth:`ResultLayers.steps`, one layer each) so that
the caller can let the event loop run between them.

A result layer is found by the field it shows (``metadata["napari_aldic"]
["field"]``), not by its name, which carries the unit (``DIC u [µm]``).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from .._analysis import Analysis
from .._layers import DISPLAY_FIELDS, MESH, UNRELIABLE, VECTORS, Display, Geometry, analysis_layers
from .inputs import is_result_layer

if TYPE_CHECKING:  # pragma: no cover
    import napari

__all__ = ["ResultLayers", "Prepared", "prepare", "DRAW", "geometry_of", "update_layer",
           "find_result_layer", "field_of"]

#: what a step yields when it makes a layer visible: napari's first drawing of it
#: follows (slow), so the caller waits longer before the next step
DRAW = "draw"
#: layer attributes that place a layer in the world
_PLACEMENT = ("scale", "translate", "units", "axis_labels")


def geometry_of(image) -> Geometry:
    """The world transform of an image layer."""
    return Geometry(scale=tuple(image.scale), translate=tuple(image.translate),
                    units=tuple(str(u) for u in image.units),
                    axis_labels=tuple(image.axis_labels))


def field_of(layer) -> str | None:
    """The result field a layer shows ("u", "exx", "displacement" ...), or None."""
    meta = getattr(layer, "metadata", None) or {}
    return (meta.get("napari_aldic") or {}).get("field")


def find_result_layer(layers, key: str):
    """The result layer of field ``key`` among ``layers`` (``None``: there is none)."""
    for lay in layers:
        if field_of(lay) == key and is_result_layer(lay):
            return lay
    return None


def _keep_colours(layer, kw: dict) -> None:
    """Put the user's colormap and contrast limits into ``kw`` where the user changed
    them: a display toggle or a new run must not undo that. Limits follow a change
    of the length scale; they are reset when rigid-body motion is added or removed."""
    old = (layer.metadata or {}).get("napari_aldic") or {}
    new = kw["metadata"]["napari_aldic"]
    if old.get("auto_colormap") and layer.colormap.name != old["auto_colormap"]:
        kw["colormap"] = layer.colormap
    auto = old.get("auto_limits")
    if auto is None or np.allclose(layer.contrast_limits, auto, rtol=1e-6, atol=0):
        return
    if old.get("rigid_removed") != new.get("rigid_removed"):
        return
    ratio = 1.0
    if DISPLAY_FIELDS.get(new["field"], ("", "strain"))[1] == "length":
        ratio = float(new["pixel_size"]) / float(old.get("pixel_size") or 1.0)
    kw["contrast_limits"] = tuple(float(c) * ratio for c in layer.contrast_limits)


def show_bar(layer, visible: bool) -> None:
    """Show or hide the canvas colour bar of a field image with, beside it, the
    layer's name, which carries the field's unit (napari 0.9's bar has no label;
    issue 24, trap 14). The name's first drawing compiles its text shader (0.1-0.3 s
    of the canvas' drawing under Mesa's software renderer, measured): drawing time,
    which test_viewer_never_stalls_during_a_run holds apart (1 s); setting it takes
    the event loop about 0.01 s."""
    layer.colorbar.visible = visible
    if visible:
        layer.name_overlay.position = layer.colorbar.position
    layer.name_overlay.visible = visible


def update_layer(layer, data, kw: dict, kind: str) -> bool:
    """Update a result layer in place (cheaper than removing and adding it; the
    user's visibility, opacity, colormap and contrast limits stay). False if it
    must be replaced."""
    ndim = len(kw["scale"])
    if layer.__class__.__name__.lower() != kind or layer.ndim != ndim or \
            kind not in ("image", "vectors", "points"):
        return False
    if kind == "image":
        _keep_colours(layer, kw)
    layer.data = data
    for key in _PLACEMENT:
        if key in kw:
            setattr(layer, key, kw[key])
    if kind == "image":
        layer.colormap = kw["colormap"]
        lo, hi = kw["contrast_limits"]
        auto = kw["metadata"]["napari_aldic"]["auto_limits"]
        layer.contrast_limits_range = (min(lo, auto[0]), max(hi, auto[1]))
        layer.contrast_limits = (lo, hi)
    elif kind == "vectors":
        layer.features = kw["features"]
        layer.length = kw["length"]
        layer.edge_width = kw["edge_width"]
        if kw.get("edge_color") == "magnitude":
            layer.edge_colormap = kw["edge_colormap"]
            layer.edge_color = "magnitude"
    else:
        layer.features = kw["features"]
        if len(data):
            layer.face_color = kw["face_color"]
            layer.size = kw["size"]
    layer.metadata = kw["metadata"]
    if layer.name != kw["name"]:
        layer.name = kw["name"]  # the unit changed
    return True


class Prepared:
    """Result layers made away from the viewer: the layer-data tuples and, when
    napari is at hand, the layer objects (both are slow for large results, so a
    worker thread makes them; only adding them needs the main thread)."""

    def __init__(self, tuples: list, display: Display, make_layers: bool = True):
        self.tuples = tuples
        self.display = display
        self.layers: list = [None] * len(tuples)
        if make_layers:
            from napari.layers import Layer

            self.layers = [Layer.create(data, dict(kw), kind) for data, kw, kind in tuples]


def prepare(analysis: Analysis, geometry: Geometry, display: Display,
            make_layers: bool = False) -> Prepared:
    """The result layers of ``analysis`` for ``display`` on an image of
    ``geometry`` (safe in a worker thread: nothing of the viewer is touched)."""
    return Prepared(analysis_layers(analysis, geometry, display), display, make_layers)


class ResultLayers:
    """The result layers of the last analysis in ``viewer``."""

    def __init__(self, viewer: napari.viewer.Viewer):
        self._viewer = viewer
        self.analysis: Analysis | None = None
        #: the image layer the analysis was computed on
        self.image = None

    def adopt(self, init_control=None) -> bool:
        """Take up the analysis already shown in the viewer (a dock opened again,
        e.g. after a language change) and the image it was computed on; a run
        from seed points sets ``init_control`` back to seeds. False: none shown."""
        for lay in self._viewer.layers:
            a = (getattr(lay, "metadata", None) or {}).get("napari_aldic_analysis")
            if a is None or not is_result_layer(lay):
                continue
            self.analysis = a
            names = [img for img in self._viewer.layers if img.name == a.source]
            self.image = names[0] if names else None
            if init_control is not None and getattr(a.params, "init", "") == "seeds":
                init_control.value = "seeds"
            return True
        return False

    @property
    def layers(self) -> list:
        """The viewer's result layers."""
        return [lay for lay in self._viewer.layers if is_result_layer(lay)]

    def layer(self, key: str):
        """The result layer of field ``key`` (``None``: not shown)."""
        return find_result_layer(self._viewer.layers, key)

    def placed_on(self, fallback_image=None):
        """The image the results are drawn on: the analysed one while it is in the
        viewer, else ``fallback_image``."""
        if self.image is not None and self.image not in self._viewer.layers:
            self.image = None
        return self.image if self.image is not None else fallback_image

    def prepare(self, display: Display, image, make_layers: bool = False) -> Prepared | None:
        """The result layers of :attr:`analysis` for ``display`` on ``image``
        (thread-safe: only the analysis and the image's transform are read)."""
        if self.analysis is None or image is None:
            return None
        return prepare(self.analysis, geometry_of(image), display, make_layers)

    def show(self, display: Display, fallback_image=None) -> None:
        """Make or update the result layers of :attr:`analysis` at once."""
        prepared = self.prepare(display, self.placed_on(fallback_image))
        if prepared is not None:
            for _ in self.steps(prepared):
                pass

    def steps(self, prepared: Prepared) -> Iterator[None]:
        """Put ``prepared`` in the viewer, one layer per step."""
        made = {kw["metadata"]["napari_aldic"]["field"] for _, kw, _ in prepared.tuples}
        for key in (VECTORS, UNRELIABLE, MESH):  # layers this display no longer makes
            old = self.layer(key)
            if key not in made and old is not None:
                self._viewer.layers.remove(old)
                yield
        for (data, kw, kind), premade in zip(prepared.tuples, prepared.layers):
            show = premade is not None and kw.get("visible", True) and \
                self.layer(kw["metadata"]["napari_aldic"]["field"]) is None
            if show:  # added hidden, shown in the next step: its first drawing is slow
                premade.visible = False
            self._put(data, kw, kind, premade)
            yield
            if show:
                premade.visible = True
                yield DRAW

    def _put(self, data, kw: dict, kind: str, premade=None) -> None:
        """Add a layer, or update the one of that field (replaced at the same place
        when it is of another kind or number of axes)."""
        layers = self._viewer.layers
        old = self.layer(kw["metadata"]["napari_aldic"]["field"])
        if old is None:
            if premade is not None:
                layers.append(premade)
            else:
                getattr(self._viewer, f"add_{kind}")(data, **kw)
            return
        if update_layer(old, data, kw, kind):
            return
        kw["visible"] = old.visible
        index = layers.index(old)
        layers.remove(old)
        new = getattr(self._viewer, f"add_{kind}")(data, **kw)
        layers.move(layers.index(new), index)

    def show_field(self, key: str) -> None:
        """Make field ``key`` the visible, active result image (its colour bar
        shown); the other field images are hidden."""
        for _ in self.field_steps(key):
            pass

    def field_steps(self, key: str) -> Iterator[None]:
        """:meth:`show_field` in three steps (visibility, colour bar, active layer)."""
        target = self.layer(key)
        for k in DISPLAY_FIELDS:
            lay = self.layer(k)
            if lay is not None:
                lay.visible = k == key
        yield DRAW
        for k in DISPLAY_FIELDS:
            lay = self.layer(k)
            if lay is not None and hasattr(lay, "colorbar"):
                show_bar(lay, k == key)
        yield DRAW
        if target is not None:
            self._viewer.layers.selection.active = target

    def go_to_last_frame(self) -> None:
        """Show the last computed frame (frame 0, the reference, is a zero field)."""
        a, img = self.analysis, self.image
        if a is None or img is None or a.n_frames is None or img not in self._viewer.layers:
            return
        done = [k for k, r in zip(a.frames, a.results) if r is not None]
        if len(done) < 2:
            return
        axis = self._viewer.dims.ndim - img.ndim  # the image's time axis in world dims
        world = float(img.translate[0]) + done[-1] * float(img.scale[0])
        self._viewer.dims.set_point(axis, world)

    def set_vector_length(self, length: float) -> bool:
        """Set the arrow length of the vectors layer; False when it must be
        recomputed (automatic length, ``length <= 0``)."""
        if length <= 0:
            return False
        layer = self.layer(VECTORS)
        if layer is not None:
            layer.length = float(length)
        return True
