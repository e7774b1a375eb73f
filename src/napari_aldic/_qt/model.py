"""The dock's model: what the analysis is, apart from the controls that show it.

As napari-animation keeps its ``Animation`` apart from the widgets, the dock
keeps one :class:`DockModel` (no Qt, no napari here): each panel writes its
part into it when a control changes, the Run button reads one
:class:`~napari_aldic._analysis.Job` from it (:meth:`DockModel.job`), and
project files and the remembered settings save and restore it
(:meth:`DockModel.storable`). Layer roles (ROI, holes, labels, refine region,
seeds) are the user's choice and stay with the layer (:func:`layer_role`),
never read from a layer's name.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from psygnal import Signal

from .._analysis import Job
from ..engine import DICParams, Settings, StrainParams, Units
from ..i18n import tr
from .sem_choice import SEMChoice

__all__ = ["DockModel", "PARAM_CONTROLS", "ROLES", "ROLE_KEY", "layer_role", "remember_role",
           "DEFAULT_PARAMS", "DEFAULT_TRACKING"]

#: where a layer keeps the role chosen for it (in ``layer.metadata``)
ROLE_KEY = "napari_aldic_role"
#: the roles a layer can have in the dock ("none": chosen for nothing)
ROLES = ("roi_add", "roi_subtract", "roi_labels", "brush", "seeds", "none")
#: the dock's starting parameters: the engine's defaults, the method excepted (the
#: dock starts on AL-DIC, the more robust of the two for a first analysis)
DEFAULT_PARAMS = DICParams(method="aldic")
DEFAULT_TRACKING = {"reference": "accumulative", "start": 0, "stop": None, "stride": 1}
#: DICParams fields that the dock shows (the others are kept from a loaded file)
PARAM_CONTROLS = ("method", "subset", "step", "search", "refine", "init", "smooth",
                  "shape_function")


def layer_role(layer) -> str | None:
    """The role chosen for ``layer`` (``None``: never chosen)."""
    role = (getattr(layer, "metadata", None) or {}).get(ROLE_KEY)
    return role if role in ROLES else None


def remember_role(layer, role: str) -> None:
    """Keep ``role`` with ``layer`` (it survives renaming, a reopened dock and
    a saved project)."""
    if role not in ROLES:
        raise ValueError(f"unknown layer role {role!r}; one of {ROLES}")
    if layer_role(layer) != role:
        layer.metadata[ROLE_KEY] = role


@dataclass
class DockModel:
    """The analysis set up in the dock (everything but the layers' data).

    ``params`` holds the shown DICParams fields and the hidden ones kept from
    a settings file, without seed points (they live in a layer) and with the
    initial guess of the controls in ``init``.

    Signals
    -------
    changed(str)
        A section ("params", "tracking", "strain", "units", "display") changed.
    """

    params: DICParams = DEFAULT_PARAMS
    init: str = "fft"
    tracking: dict = field(default_factory=lambda: dict(DEFAULT_TRACKING))
    strain: StrainParams = field(default_factory=StrainParams)
    units: Units | None = None
    display: dict = field(default_factory=dict)
    #: SEM corrections (issue 27): kept with a project, not with the remembered settings
    sem: SEMChoice | None = None

    changed = Signal(str)

    def update(self, section: str, value: Any) -> None:
        """Set one section (a panel writes its part); ``changed`` when it differs."""
        if section not in ("params", "init", "tracking", "strain", "units", "display",
                           "sem"):
            raise KeyError(section)
        if getattr(self, section) != value:
            setattr(self, section, value)
            self.changed.emit(section)

    # ------------------------------------------------------------ reading
    def run_params(self, seeds: tuple = ()) -> DICParams:
        """The parameters of a run: the model's with its initial guess and ``seeds``."""
        return self.params.replace(init=self.init, seeds=tuple(seeds) if self.init == "seeds"
                                   else ())

    def job(self, stack, roi, *, brush=None, seeds: tuple = (), source: str = "",
            notes: list[str] | None = None) -> Job:
        """The one job the Run button starts: the model's parameters, tracking and
        strain on ``stack`` with ``roi`` (``notes``: how the ROI was made)."""
        t = {**DEFAULT_TRACKING, **self.tracking}
        job = Job(stack=stack, roi=roi, params=self.run_params(seeds),
                  reference=t["reference"], start=int(t["start"]),
                  stop=None if t["stop"] is None else int(t["stop"]), stride=int(t["stride"]),
                  brush=brush, strain=self.strain, source=source,
                  sem=self.sem.options() if self.sem and self.sem.active else None,
                  units=self.units)
        job.summary = job.describe(notes or [], self.hidden_params())
        if job.sem is not None:  # issue 27: refused before the run starts, and logged
            if job.n_deformed != 1 or (brush is not None and brush.any()):
                raise ValueError(tr("SEM corrections apply to a pair: choose a frame range "
                                    "with one deformed frame and no brush refinement region"))
            job.summary += "; " + tr("SEM corrections: {parts}").format(parts=self.sem.words())
        return job

    def hidden_params(self) -> dict:
        """DICParams fields the dock does not show that differ from the defaults."""
        base, mine = DICParams().to_dict(), self.params.to_dict()
        return {k: v for k, v in mine.items()
                if k not in PARAM_CONTROLS and k != "seeds" and v != base[k]}

    def settings(self, seeds: tuple = (), probes: dict | None = None) -> Settings:
        """The complete settings (a settings file's document)."""
        return Settings(self.run_params(seeds), self.units, self.strain.to_dict(),
                        dict(self.tracking), probes=probes)

    def storable(self, frame_range: bool = True) -> dict:
        """What a project file or the remembered settings keep: ``{"settings":
        Settings document, "init", "display"}``, without seed points. The
        remembered settings (``frame_range=False``) keep neither the frame
        range nor the calibration: both belong to one image."""
        tracking = dict(self.tracking)
        units = self.units
        if not frame_range:
            tracking = {k: tracking[k] for k in ("reference", "stride") if k in tracking}
            units = None
        s = Settings(replace(self.params, init="fft", seeds=()), units, self.strain.to_dict(),
                     tracking)
        doc = {"settings": s.to_dict(), "init": self.init, "display": dict(self.display)}
        if frame_range and self.sem is not None:
            doc["sem"] = self.sem.to_dict()
        return doc
