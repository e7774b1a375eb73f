"""The Input panel: the image stack and the layers that shape the analysis.

Shapes layers add to or cut holes in the ROI, Labels restrict it or mark where the
mesh is refined, Points hold seeds. A layer's role is the user's choice in the combos
and stays with the layer (:func:`~.model.layer_role`; renaming it or reopening the
dock changes nothing): no layer is a hole unless chosen as one.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from typing import TYPE_CHECKING, Any

import numpy as np
from magicgui.widgets import ComboBox, Container, PushButton, Select
from psygnal import Signal

from .._layers import is_result_name
from .._roi import build_roi, labels_fit, labels_mask, points_xy
from ..i18n import tr
from .controls import Panel
from .model import layer_role, remember_role
from .project import is_probe_layer

if TYPE_CHECKING:  # pragma: no cover
    import napari

__all__ = ["InputsPanel", "is_result_layer"]


def is_result_layer(layer) -> bool:
    """Whether ``layer`` is one of the plugin's result layers (never an input)."""
    meta = getattr(layer, "metadata", {}) or {}
    return ("napari_aldic_analysis" in meta or "field" in (meta.get("napari_aldic") or {})
            or is_result_name(layer.name))


class OptionalLayer(ComboBox):
    """A layer choice that may be empty; choosing "(none)" is a change like any other
    (magicgui does not report a change to ``None`` unless the choice is nullable)."""

    null_string = "(none)"

    def __init__(self, **kwargs):
        self.null_string = tr("(none)")  # shown; the value stays None
        super().__init__(nullable=True, **kwargs)


class InputsPanel(Panel):
    """Choose the image stack, ROI shapes, holes, ROI labels, refine region and seeds.

    Signals
    -------
    inputs_changed
        A choice, the layer list or a chosen layer's data changed: re-check.
    seeds_assigned
        A Points layer named like 'seed' was chosen automatically.
    """

    inputs_changed = Signal()
    seeds_assigned = Signal()

    def __init__(self, viewer: napari.viewer.Viewer):
        self._viewer = viewer
        self._chosen: dict[str, list] = {}  # the ROI and holes chosen last
        super().__init__()

    # ------------------------------------------------------------ setup
    def _layers_of(self, kind: str):
        def choices(_widget=None):
            import napari.layers as nl

            cls = getattr(nl, kind)
            return [(lay.name, lay) for lay in self._viewer.layers  # probes shape no input
                    if isinstance(lay, cls) and not (is_result_layer(lay) or is_probe_layer(lay))]
        return choices

    def _setup_ui(self) -> None:
        layers_of = self._layers_of
        self.image = ComboBox(label=tr("Image stack"), choices=layers_of("Image"), nullable=True,
                              tooltip=tr("Image layer with a time axis (frames, rows, cols); the "
                                      "first frame of the range is the reference."))
        self.roi_add = Select(label=tr("ROI (shapes)"), choices=layers_of("Shapes"),
                              tooltip=tr("Shapes layers whose rectangles, polygons and ellipses "
                                      "are analysed (union). None selected: whole image.\n"
                                      "Lines and paths in any chosen layer cut the ROI "
                                      "(cracks)."))
        self.roi_subtract = Select(label=tr("Holes (shapes)"), choices=layers_of("Shapes"),
                                   tooltip=tr("Shapes layers whose shapes are removed from the "
                                           "ROI (holes, notches, background). A layer is a "
                                           "hole only when chosen here; the choice stays "
                                           "with the layer."))
        self.roi_labels = OptionalLayer(label=tr("ROI labels"), choices=layers_of("Labels"),
                                        tooltip=tr("Labels layer: nonzero pixels are analysed "
                                                "(intersected with the ROI shapes). It is "
                                                "matched to the image through world "
                                                "coordinates."))
        self.brush = OptionalLayer(label=tr("Refine region"), choices=layers_of("Labels"),
                                   tooltip=tr("Labels layer painted with the brush: the mesh is "
                                           "refined where it is nonzero (quadtree)."))
        self.seeds = OptionalLayer(label=tr("Seeds (points)"), choices=layers_of("Points"),
                                   tooltip=tr("Points layer of seed points for the 'seed "
                                           "points' initial guess: at least one per "
                                           "connected ROI region, on well-textured "
                                           "material."))
        self.new_roi_labels = PushButton(text=tr("New ROI labels"),
                                         tooltip=tr("A Labels layer of the image's size to "
                                                 "paint the analysed region in."))
        self.new_refine = PushButton(text=tr("New refine region"),
                                     tooltip=tr("A Labels layer of the image's size to paint "
                                             "where the mesh is refined."))
        buttons = Container(widgets=[self.new_roi_labels, self.new_refine],
                            layout="horizontal", labels=False)
        buttons.margins = (0, 0, 0, 0)
        self.extend([self.image, self.roi_add, self.roi_subtract, self.roi_labels,
                     self.brush, self.seeds, buttons])
        for sel in (self.roi_add, self.roi_subtract):
            sel.native.setMaximumHeight(64)

    def _setup_callbacks(self) -> None:
        layers = self._viewer.layers
        layers.events.inserted.connect(self._on_inserted)
        layers.events.removed.connect(self._on_layers_changed)
        layers.events.moved.connect(self._on_layers_changed)
        for lay in list(layers):
            self._watch(lay)
        for w in (self.roi_add, self.roi_subtract, self.roi_labels, self.brush, self.seeds):
            w.changed.connect(self._emit_changed)
        self.roi_add.changed.connect(lambda *_: self._remember_roles(self.roi_add))
        self.roi_subtract.changed.connect(lambda *_: self._remember_roles(self.roi_subtract))
        self.new_roi_labels.changed.connect(lambda *_: self.new_labels("roi_labels"))
        self.new_refine.changed.connect(lambda *_: self.new_labels("brush"))

    def assign_existing_layers(self) -> None:
        """Preselect inputs among the layers already in the viewer."""
        for lay in list(self._viewer.layers):
            self.auto_assign(lay)

    def disconnector(self) -> Callable[[], None]:
        """A function that stops following the viewer's layers (the widget is
        closed). It holds what it needs, so it works while the panel is torn down."""
        layers = self._viewer.layers
        on_inserted, on_changed, on_data, on_renamed = (
            self._on_inserted, self._on_layers_changed, self._emit_changed, self._on_renamed)

        def disconnect() -> None:
            for emitter, slot in ((layers.events.inserted, on_inserted),
                                  (layers.events.removed, on_changed),
                                  (layers.events.moved, on_changed)):
                emitter.disconnect(slot)
            for lay in list(layers):
                lay.events.name.disconnect(on_renamed)
                if hasattr(lay.events, "data"):
                    lay.events.data.disconnect(on_data)
        return disconnect

    # ------------------------------------------------------------ layer list
    def _emit_changed(self, *_) -> None:
        self.inputs_changed.emit()

    def _watch(self, layer) -> None:
        layer.events.name.connect(self._on_renamed)
        if layer.__class__.__name__ in ("Shapes", "Labels", "Points"):
            layer.events.data.connect(self._emit_changed)

    def _on_inserted(self, event=None) -> None:
        layer = getattr(event, "value", None)
        if layer is not None:
            self._watch(layer)
            if is_result_layer(layer):
                return  # never an input: nothing to update
        self.refresh_choices()
        if layer is not None:
            self.auto_assign(layer)
        if self.image.value is None:
            self.choose_first_image()
        self.inputs_changed.emit()

    def _on_layers_changed(self, event=None) -> None:
        layer = getattr(event, "value", None)
        if layer is not None and is_result_layer(layer) and getattr(event, "type", "") == \
                "removed":
            return
        self.refresh_choices()
        self.inputs_changed.emit()

    def _on_renamed(self, event=None) -> None:
        """A layer was renamed: the choices follow the layer object, and a name that
        now says what the layer is for (e.g. 'hole', 'refine') is read again."""
        layer = getattr(event, "source", None)
        if layer is not None and is_result_layer(layer):
            return
        self.refresh_choices()
        if layer is not None:
            self.auto_assign(layer, renamed=True)
        self.inputs_changed.emit()

    def refresh_choices(self) -> None:
        """Rebuild the choices from the layer list, keeping every chosen layer that is
        still there (magicgui matches choices by name, which a rename changes)."""
        layers = list(self._viewer.layers)

        def present(lay) -> bool:
            return any(lay is other for other in layers)

        combos = (self.image, self.roi_labels, self.brush, self.seeds)
        selects = (self.roi_add, self.roi_subtract)
        before = {w: w.value for w in combos} | {w: list(w.value) for w in selects}
        with ExitStack() as stack:
            for w in (*combos, *selects):
                stack.enter_context(w.changed.blocked())
            self.reset_choices()
            for w in combos:
                if before[w] is not None and present(before[w]):
                    w.value = before[w]
            for w in selects:
                w.value = [lay for lay in before[w] if present(lay)]
        for w in (*combos, *selects):
            now = w.value if w in combos else list(w.value)
            if now is not before[w] and now != before[w]:
                w.changed.emit(now)

    def _remember_roles(self, chosen) -> None:
        """The user's choice of ROI and holes (``chosen``: the one just changed) stays
        with each Shapes layer; a layer is in one of the two at most."""
        other = self.roi_subtract if chosen is self.roi_add else self.roi_add
        now = list(chosen.value)
        keep = [lay for lay in other.value if not any(lay is x for x in now)]
        if len(keep) != len(other.value):
            with other.changed.blocked():
                other.value = keep
        role = "roi_add" if chosen is self.roi_add else "roi_subtract"
        for lay in now:
            remember_role(lay, role)
        for lay in self._chosen.get(role, []):
            if not any(lay is x for x in now) and layer_role(lay) == role:
                remember_role(lay, "none")
        self._chosen = {"roi_add": list(self.roi_add.value),
                        "roi_subtract": list(self.roi_subtract.value)}

    def auto_assign(self, layer, renamed: bool = False) -> None:
        """Preselect a layer's input: the role chosen for it before (kept with the
        layer), else a new Shapes layer adds to the ROI (never a hole by its name:
        napari names a new Shapes layer after the image, 'open_hole - Shapes');
        Labels 'roi' -> ROI labels, 'refine'/'brush' -> refinement region (only
        labels that fit the chosen image); Points 'seed' -> seeds.

        ``renamed``: the layer was renamed; its role does not change."""
        kind = layer.__class__.__name__
        name = layer.name.lower()
        if is_probe_layer(layer):
            return  # a probe (gauge, area, point) measures; it shapes no input
        if kind == "Shapes":
            if not renamed:
                self._place_shapes(layer, layer_role(layer) or "roi_add")
        elif kind == "Labels":
            img = self.image.value
            if img is not None and not labels_fit(layer, img):
                return  # another image's labels (e.g. of a second sample)
            if ("refine" in name or "brush" in name) and self.brush.value is None:
                self.brush.value = layer
            elif "roi" in name and self.roi_labels.value is None:
                self.roi_labels.value = layer
        elif kind == "Points" and "seed" in name and self.seeds.value is None:
            self.seeds.value = layer
            self.seeds_assigned.emit()

    def _place_shapes(self, layer, role: str) -> None:
        """Put a Shapes layer in the ROI or the holes (or neither) as ``role`` says."""
        add = [lay for lay in self.roi_add.value if lay is not layer]
        sub = [lay for lay in self.roi_subtract.value if lay is not layer]
        if role == "roi_add":
            add.append(layer)
        elif role == "roi_subtract":
            sub.append(layer)
        if add != list(self.roi_add.value):
            self.roi_add.value = add
        if sub != list(self.roi_subtract.value):
            self.roi_subtract.value = sub

    def match_image(self) -> None:
        """The chosen image changed: labels that do not fit it are let go, and the
        ones named for it that fit are chosen."""
        img = self.image.value
        if img is None:
            return
        for combo in (self.roi_labels, self.brush):
            if combo.value is not None and not labels_fit(combo.value, img):
                combo.value = None
        for lay in list(self._viewer.layers):
            if lay.__class__.__name__ == "Labels" and not is_result_layer(lay):
                self.auto_assign(lay, renamed=True)

    def new_labels(self, role: str):
        """A new Labels layer of the chosen image's size and placement, chosen as the
        ROI labels (``role="roi_labels"``) or the refine region (``"brush"``)."""
        img = self.image.value
        if img is None:
            raise ValueError(tr("choose an image stack first"))
        shape = tuple(self.stack_data.shape[-2:])
        name = tr("ROI labels") if role == "roi_labels" else tr("refine region")
        layer = self._viewer.add_labels(np.zeros(shape, np.uint8), name=name,
                                        scale=tuple(img.scale)[-2:],
                                        translate=tuple(img.translate)[-2:], opacity=0.4)
        getattr(self, role).value = layer
        layer.mode = "paint"
        self._viewer.layers.selection.active = layer
        return layer

    def choose_first_image(self) -> bool:
        """Choose the first image layer when none is chosen; True if one was."""
        if self.image.value is not None:
            return False
        candidates = [c for c in self.image.choices if c is not None]
        if candidates:
            self.image.value = candidates[0]
        return bool(candidates)

    # ------------------------------------------------------------ state
    @property
    def image_layer(self):
        """The chosen image layer (``None``: none chosen)."""
        return self.image.value

    @property
    def stack_data(self):
        """The image data (its full-resolution level when multiscale), or ``None``."""
        img = self.image.value
        if img is None:
            return None
        return img.data[0] if img.multiscale else img.data

    @property
    def stack_shape(self) -> tuple | None:
        """Shape of the chosen image's data, ``None`` without an image."""
        data = self.stack_data
        return None if data is None else tuple(data.shape)

    @property
    def input_layers(self) -> list:
        """The image and every chosen input layer, each once."""
        out = [self.image.value, *self.roi_add.value, *self.roi_subtract.value,
               self.roi_labels.value, self.brush.value, self.seeds.value]
        seen, uniq = set(), []
        for lay in out:
            if lay is not None and id(lay) not in seen:
                seen.add(id(lay))
                uniq.append(lay)
        return uniq

    def roi(self, image_shape, frame: int = 0) -> tuple[np.ndarray | None, list[str]]:
        """The analysis ROI of the chosen layers (``None``: whole image) and notes."""
        return build_roi(self.image.value, image_shape, add_shapes=list(self.roi_add.value),
                         subtract_shapes=list(self.roi_subtract.value),
                         labels=self.roi_labels.value, frame=frame)

    def brush_mask(self, image_shape, frame: int = 0) -> np.ndarray | None:
        """The painted refine region (``None``: no layer or nothing painted)."""
        if self.brush.value is None:
            return None
        mask = labels_mask(self.brush.value, image_shape, frame, self.image.value)
        return mask if mask.any() else None

    def seed_points(self) -> tuple:
        """Seed points ``(x, y)`` in image pixels (``ValueError`` without points)."""
        layer = self.seeds.value
        if layer is None or len(layer.data) == 0:
            raise ValueError(tr("the initial guess 'Seed points' needs a Points layer with at "
                                "least one point (choose it under 'Seeds (points)')"))
        img = self.image.value
        xy = (points_xy(layer, img) if img is not None
              else np.asarray(layer.data, float)[:, -2:][:, ::-1])
        return tuple((float(x), float(y)) for x, y in xy)

    def restore_seeds(self, seeds, notes: list[str]) -> None:
        """Seed points ``(x, y)`` in image pixels as a new Points layer, unless a
        seeds layer with points is chosen already (a note says which)."""
        layer = self.seeds.value
        if layer is not None and len(layer.data):
            notes.append(tr("the file's {n_seeds} seed point(s) were not added: the seeds "
                            "layer '{name}' is used").format(
                                n_seeds=len(seeds), name=layer.name))
            return
        img = self.image.value
        rc = np.array([(y, x) for x, y in seeds], float)
        kwargs: dict[str, Any] = {}
        if img is not None:  # the image's pixel grid (its current scale and offset)
            kwargs = {"scale": tuple(img.scale)[-2:], "translate": tuple(img.translate)[-2:]}
        new = self._viewer.add_points(rc, name=tr("seeds (loaded)"), size=6, face_color="cyan",
                                      **kwargs)
        if img is not None:
            try:
                new.units = [str(u) for u in img.units][-2:]
            except Exception:  # units are cosmetic here; the scale is what counts
                pass
        self.seeds.value = new
        notes.append(tr("{n_seeds} seed point(s) from the file added as the Points "
                        "layer '{name}'").format(
                            n_seeds=len(seeds), name=new.name))
