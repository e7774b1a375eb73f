"""Digital volume correlation (DVC): Local 3-D IC-GN and AL-DVC on volumes.

Reuses the engine's structure (parameters :class:`~..core.params.DICParams`
in voxels, reasons :class:`~..core.reasons.Reason`, the result file
machinery) with its own 3-D kernels (``kernels/icgn3d.py``,
``kernels/bspline3d.py``). The public entry is
:func:`~.correlate.correlate_volume`.
"""

from ..io.volumes import open_volume  # re-exported: the blocked entry reads through it
from .correlate import correlate_volume
from .export import export_volume
from .strain import MEASURES3, VolumeStrain, compute_strain_volume
from .track import compose_increment, track_volumes

__all__ = ["correlate_volume", "compute_strain_volume", "VolumeStrain", "MEASURES3",
           "export_volume", "track_volumes", "compose_increment",
           "open_volume"]
