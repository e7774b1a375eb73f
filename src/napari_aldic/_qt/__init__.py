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

Qt-free helpers: :mod:`.checks` (the input check before a run), :mod:`.results`
(result layers in the viewer), :mod:`.project` (project files), :mod:`.prefs`
(the last used parameters) and :mod:`.warmup` (preparing the Numba kernels).
"""

from .correlation import CorrelationPanel
from .display import DisplayPanel
from .export import ExportPanel
from .inputs import InputsPanel
from .run import RunPanel
from .settings import SettingsPanel
from .strain import StrainPanel
from .units import UnitsPanel
from .widget import DICWidget

__all__ = ["DICWidget", "InputsPanel", "CorrelationPanel", "StrainPanel", "UnitsPanel",
           "DisplayPanel", "ExportPanel", "SettingsPanel", "RunPanel"]
