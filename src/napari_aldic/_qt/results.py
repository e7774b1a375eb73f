"""Result layers in the viewer: add, update in place or replace them (no Qt here).

:class:`ResultLayers` holds the last analysis and the image it was computed
on, and turns them into the viewer's ``DIC ...`` layers with
:func:`napari_aldic._layers.analysis_layers`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._analysis import Analysis
from .._layers import Display, Geometry, analysis_layers, layer_name
from .inputs import is_result_layer

if TYPE_CHECKING:  # pragma: no cover
    import napari

__all__ = ["ResultLayers", "geometry_of", "update_layer"]

#: layer attributes that place a layer in the world
_PLACEMENT = ("scale", "translate", "units", "axis_labels")


def geometry_of(image) -> Geometry:
    """The world transform of an image layer."""
    return Geometry(scale=tuple(image.scale), translate=tuple(image.translate),
                    units=tuple(str(u) for u in image.units),
                    axis_labels=tuple(image.axis_labels))


def update_layer(layer, data, kw: dict, kind: str) -> bool:
    """Update a result layer in place (cheaper than removing and adding it, and
    the user's visibility and opacity stay). False if it must be replaced."""
    ndim = len(kw["scale"])
    if layer.__class__.__name__.lower() != kind or layer.ndim != ndim or \
            kind not in ("image", "vectors", "points"):
        return False
    layer.data = data
    for key in _PLACEMENT:
        if key in kw:
            setattr(layer, key, kw[key])
    if kind == "image":
        layer.colormap = kw["colormap"]
        layer.contrast_limits_range = kw["contrast_limits"]
        layer.contrast_limits = kw["contrast_limits"]
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
    return True


class ResultLayers:
    """The result layers of the last analysis in ``viewer``."""

    def __init__(self, viewer: napari.viewer.Viewer):
        self._viewer = viewer
        self.analysis: Analysis | None = None
        #: the image layer the analysis was computed on
        self.image = None

    @property
    def layers(self) -> list:
        """The viewer's result layers."""
        return [lay for lay in self._viewer.layers if is_result_layer(lay)]

    def show(self, display: Display, fallback_image=None) -> None:
        """Make or update the result layers of :attr:`analysis` (placed on the
        analysed image, or on ``fallback_image`` when that one was removed)."""
        layers = self._viewer.layers
        if self.analysis is None:
            return
        if self.image is not None and self.image not in layers:
            self.image = None
        image = self.image if self.image is not None else fallback_image
        if image is None:
            return
        tuples = analysis_layers(self.analysis, geometry_of(image), display)
        made = {kw["name"] for _, kw, _ in tuples}
        # layers this display no longer makes (e.g. mesh switched off) go away
        for key in ("displacement", "unreliable nodes", "mesh"):
            name = layer_name(key)
            if name not in made and name in layers:
                layers.remove(name)
        for data, kw, kind in tuples:
            self._put(data, kw, kind)
        vis = layer_name(display.visible_field)
        if vis in layers and hasattr(layers[vis], "colorbar"):
            layers[vis].colorbar.visible = True

    def _put(self, data, kw: dict, kind: str) -> None:
        """Add a layer, or update the one of that name (replaced at the same place
        when it is of another kind or number of axes)."""
        layers = self._viewer.layers
        name = kw["name"]
        if name not in layers:
            getattr(self._viewer, f"add_{kind}")(data, **kw)
            return
        old = layers[name]
        if update_layer(old, data, kw, kind):
            return
        kw["visible"] = old.visible
        index = layers.index(old)
        layers.remove(old)
        new = getattr(self._viewer, f"add_{kind}")(data, **kw)
        layers.move(layers.index(new), index)

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
        name = layer_name("displacement")
        if name in self._viewer.layers:
            self._viewer.layers[name].length = float(length)
        return True
