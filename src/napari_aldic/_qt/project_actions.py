"""Save and open project files from the dock widget (see :mod:`.project`).

Opening a project: the whole file is read and checked first (nothing changes
when it is invalid); then the image is opened (or reused when the viewer has
it already), chosen, the settings applied (units rescale the image), and the
stored layers added with their roles and the display choices restored.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..engine import Settings
from ..i18n import tr, tr_noop
from .explain import message
from .model import DockModel
from .probes import find_analysis
from .project import (
    image_changed,
    image_record,
    is_probe_layer,
    layer_data,
    layer_record,
    read_project,
    write_project,
)
from .project_results import LOAD_KEY, load_record, restore_load, restore_results, results_record
from .sem_choice import SEMChoice

__all__ = ["ProjectActions", "PROJECT_FILTER"]

PROJECT_FILTER = tr_noop("napari-aldic analysis (*.json);;All files (*)")
_CHOICES = ("roi_add", "roi_subtract")
_SINGLE = ("roi_labels", "brush", "seeds")


def _same_path(layer, path) -> bool:
    meta = layer.metadata or {}
    src = getattr(getattr(layer, "source", None), "path", None) or meta.get("source")
    if isinstance(path, list) or isinstance(src, list):
        return [str(p) for p in (src or [])] == [str(p) for p in (path or [])]
    return src is not None and Path(str(src)) == Path(str(path))


class ProjectActions:
    """Project files of the dock's :class:`~.model.DockModel` and its layers.

    A document is the model's :meth:`~.model.DockModel.storable` plus the image
    and the layers with their roles. ``parent`` is the panel that applies a
    document's settings to the controls (``apply``, ``set_init``,
    ``set_display``) and places the file dialogs (``start_folder``, ``stem``);
    it is passed in, never imported (no cycle).
    """

    def __init__(self, model: DockModel, inputs, viewer, log: Callable[[str], None], *,
                 parent):
        self._model, self._panel, self._viewer, self._log = model, parent, viewer, log
        self._inputs = inputs
        #: the analysis of the project opened last (its saved results), or None
        self.restored = None

    # ------------------------------------------------------------ saving
    def document(self) -> dict:
        """The project document of the widget's current set-up."""
        from .. import __version__

        img = self._inputs.image_layer
        if img is None:
            raise ValueError(tr("choose an image stack first"))
        records, seen = [], set()
        for role in _CHOICES:
            for lay in getattr(self._inputs, role).value:
                records.append(layer_record(lay, role))
                seen.add(id(lay))
        for role in _SINGLE:
            lay = getattr(self._inputs, role).value
            if lay is not None:
                records.append(layer_record(lay, role))
                seen.add(id(lay))
        for lay in self._viewer.layers:  # probes, used by the probe dock
            if is_probe_layer(lay) and id(lay) not in seen:
                records.append(layer_record(lay, "probe"))
        return {"software": f"napari-aldic {__version__}", "image": image_record(img),
                **self._panel.storable(), "layers": records}

    def save(self, path) -> Path | None:
        """Write the project file ``path``; ``None`` after an error notification."""
        from napari.utils.notifications import show_error

        try:
            path = Path(os.fspath(path)).expanduser()
            path = path if path.suffix else path.with_suffix(".json")
            doc = self.document()
            doc.update(self._kept_with(path))
            written = write_project(path, doc)
        except Exception as exc:  # nothing to refer to, unwritable file: explain
            self._log(tr("ERROR saving the analysis to {path}: {exc}").format(
                             path=path, exc=message(exc)))
            show_error(tr("napari-aldic: could not save the analysis: {exc}").format(
                              exc=message(exc)))
            return None
        self._log(tr("analysis saved to {written}").format(written=written))
        return written

    def _kept_with(self, path: Path) -> dict:
        """The results (written beside the project) and the probe dock's load file."""
        kept: dict = {}
        view = find_analysis(self._viewer.layers)
        if view is not None and view.analysis is not None:
            kept["results"] = results_record(view.analysis, path, self._model.units)
        for lay in self._viewer.layers:
            load = (getattr(lay, "metadata", None) or {}).get(LOAD_KEY)
            if is_probe_layer(lay) and isinstance(load, dict):
                rec = load_record(load, path)
                if rec is not None:
                    kept["load"] = rec
                    break
        return kept

    def _restore_kept(self, doc: dict, path, image) -> None:
        """The saved results (``self.restored``) and the load file on the probes."""
        self.restored = None
        if isinstance(doc.get("results"), dict):
            try:
                self.restored = restore_results(doc["results"], path, image.name)
            except (ValueError, OSError) as exc:
                self._log(tr("the saved results were not restored: {exc}; run the analysis "
                             "again").format(exc=message(exc)))
        if isinstance(doc.get("load"), dict):
            try:
                load = restore_load(doc["load"], path)
            except ValueError as exc:
                self._log(tr("the load file was not restored: {exc}").format(
                    exc=message(exc)))
                return
            probes = [lay for lay in self._viewer.layers
                      if is_probe_layer(lay) and lay.__class__.__name__ == "Shapes"]
            if probes:
                probes[0].metadata = {**probes[0].metadata, LOAD_KEY: load}

    # ------------------------------------------------------------ opening
    def open(self, path) -> bool:
        """Open the project file ``path``; ``False`` after an error notification."""
        from napari.utils.notifications import show_error

        try:
            doc = read_project(path)
            settings = Settings.from_dict(doc.get("settings") or {})
            sem = SEMChoice.from_dict(doc.get("sem"))  # issue 27: files checked by its panel
            image = self._image(doc["image"])
            shape, data = doc["image"].get("shape"), image.data
            now = list(np.shape(data[0] if getattr(image, "multiscale", False) else data))
            if isinstance(shape, list) and now != shape:
                raise ValueError(image_changed(doc["image"].get("path"),
                                               f"shape {shape} -> {now}"))
        except Exception as exc:  # invalid file or missing image: nothing is changed
            self._log(tr("ERROR opening the analysis {path}: {exc}").format(
                             path=path, exc=message(exc)))
            show_error(tr("napari-aldic: could not open the analysis: {exc}").format(
                              exc=message(exc)))
            return False
        self._inputs.image.value = image
        init = doc.get("init") or "fft"
        self._panel.apply(settings, str(path), "fft")
        self._add_layers(doc.get("layers", []), image)
        if init == "seeds" and self._inputs.seeds.value is not None:
            self._panel.set_init("seeds")
        self._panel.set_display(doc.get("display") or {})
        self._model.update("sem", sem)
        self._restore_kept(doc, path, image)
        self._viewer.reset_view()  # the project's image in view (not a speck of the old view)
        self._log(tr("analysis opened from {path}: image '{image_name}', {n_get} "
                     "layer(s)").format(
                         path=path, image_name=image.name, n_get=len(doc.get('layers', []))))
        self._panel.project_opened.emit()
        return True

    def _image(self, rec: dict):
        """The project's image layer: the one in the viewer, or opened now."""
        import napari.layers as nl

        path, sample = rec.get("path"), rec.get("sample")
        for lay in self._viewer.layers:
            if isinstance(lay, nl.Image) and (
                    (path and _same_path(lay, path)) or
                    (sample and tuple(getattr(lay.source, "sample", None) or ()) ==
                     tuple(sample))):
                return lay
        if sample:
            added = self._viewer.open_sample(sample[0], sample[1])
            images = [lay for lay in added if isinstance(lay, nl.Image)]
            for lay in added:  # the project's own layers replace the sample's extras
                if lay not in images[:1]:
                    self._viewer.layers.remove(lay)
            return images[0]
        paths = path if isinstance(path, list) else [path]
        missing = [p for p in paths if not Path(os.fspath(p)).exists()]
        if missing:
            raise FileNotFoundError(tr("the image {path} of the project is not there (moved "
                                       "or renamed?); put it back or edit the 'path' in the "
                                       "project file").format(path=missing[0]))
        from .._reader import get_reader

        plugin = "napari-aldic" if get_reader(path) is not None else None
        added = self._viewer.open(path, plugin=plugin, stack=isinstance(path, list) and
                                  plugin is None)
        images = [lay for lay in added if isinstance(lay, nl.Image)]
        if not images:
            raise ValueError(tr("{path} did not open as an image").format(path=path))
        return images[0]

    def _add_layers(self, records: list, image) -> None:
        """Add the stored layers (after the units: they carry their own scale, and
        take the image's unit names) and choose them for their roles."""
        from napari.layers import Layer

        chosen: dict[str, list] = {role: [] for role in (*_CHOICES, *_SINGLE)}
        for rec in records:
            data, kw, kind = layer_data(rec)
            layer = self._viewer.add_layer(Layer.create(data, kw, kind))
            try:  # the same length unit as the image (not "pixel" beside mm)
                layer.units = [str(u) for u in image.units][-layer.ndim:]
            except (ValueError, TypeError):  # another number of axes: left as stored
                pass
            if rec["role"] in chosen:
                chosen[rec["role"]].append(layer)
        for role in _CHOICES:
            getattr(self._inputs, role).value = chosen[role]
        for role in _SINGLE:
            if chosen[role]:
                getattr(self._inputs, role).value = chosen[role][0]

    # ------------------------------------------------------------ dialogs
    def on_save_clicked(self, *_) -> None:
        from qtpy.QtWidgets import QFileDialog

        start = self._panel.start_folder(f"{self._panel.stem()}_analysis.json")
        path, _ = QFileDialog.getSaveFileName(self._panel.native, tr("Save the analysis"),
                                              start, tr(PROJECT_FILTER))
        if path:
            self.save(path)

    def on_open_clicked(self, *_) -> None:
        from qtpy.QtWidgets import QFileDialog

        path, _ = QFileDialog.getOpenFileName(self._panel.native, tr("Open an analysis"),
                                              self._panel.start_folder(), tr(PROJECT_FILTER))
        if path:
            self.open(path)
