"""The napari dock widget, one panel per file.

* :mod:`.inputs` -- :class:`InputsPanel`: image stack, ROI/holes shapes, ROI labels,
  refine region, seeds;
* :mod:`.correlation` -- :class:`CorrelationPanel`: DIC parameters, tracking, frames;
* :mod:`.strain` -- :class:`StrainPanel`; :mod:`.units` -- :class:`UnitsPanel`;
* :mod:`.display` -- :class:`DisplayPanel`: which result layers and how;
* :mod:`.export` -- :class:`ExportPanel`: every format the engine writes;
* :mod:`.settings` -- :class:`SettingsPanel`: project and settings files, defaults,
  the last used parameters (:mod:`.project_actions` opens and saves projects);
* :mod:`.run` -- :class:`RunPanel`: status, Run/Cancel, progress and log;
* :mod:`.layout` -- the collapsible sections in one scroll area;
* :mod:`.widget` -- :class:`DICWidget`, the dock widget that composes them.

Qt-free: :mod:`.model` (:class:`~.model.DockModel`, the analysis set up in the dock: the
panels write it, Run reads its job, projects save and restore it), :mod:`.checks` (the
input check before a run), :mod:`.results` (result layers in the viewer), :mod:`.project`
(project files), :mod:`.prefs` (the last used parameters) and :mod:`.warmup` (preparing
the Numba kernels).
"""

from importlib import import_module

__all__ = ["DICWidget", "InputsPanel", "CorrelationPanel", "StrainPanel", "UnitsPanel",
           "DisplayPanel", "ExportPanel", "SettingsPanel", "RunPanel"]

#: each panel's module: imported when first asked for, so that the Qt-free modules
#: (the model, the checks, project files) can be imported without Qt
_HOMES = {"DICWidget": "widget", "InputsPanel": "inputs", "CorrelationPanel": "correlation",
          "StrainPanel": "strain", "UnitsPanel": "units", "DisplayPanel": "display",
          "ExportPanel": "export", "SettingsPanel": "settings", "RunPanel": "run"}


def __getattr__(name: str):
    if name in _HOMES:
        return getattr(import_module(f".{_HOMES[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
