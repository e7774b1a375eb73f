"""The napari dock widget, one panel per file.

* :mod:`.inputs` -- :class:`InputsPanel`: image stack, ROI/holes shapes, ROI labels,
  refine region, seeds;
* :mod:`.correlation` -- :class:`CorrelationPanel`: DIC parameters, tracking, frames;
* :mod:`.strain` -- :class:`StrainPanel`; :mod:`.units` -- :class:`UnitsPanel`;
* :mod:`.display` -- :class:`DisplayPanel`: which result layers and how;
* :mod:`.settings` -- :class:`SettingsPanel`: save/load the settings file;
* :mod:`.run` -- :class:`RunPanel`: status, Run/Cancel, progress and log;
* :mod:`.widget` -- :class:`DICWidget`, the dock widget that composes them.

Qt-free helpers: :mod:`.checks` (the input check before a run) and
:mod:`.results` (result layers in the viewer).
"""

from .correlation import CorrelationPanel
from .display import DisplayPanel
from .inputs import InputsPanel
from .run import RunPanel
from .settings import SettingsPanel
from .strain import StrainPanel
from .units import UnitsPanel
from .widget import DICWidget

__all__ = ["DICWidget", "InputsPanel", "CorrelationPanel", "StrainPanel", "UnitsPanel",
           "DisplayPanel", "SettingsPanel", "RunPanel"]
