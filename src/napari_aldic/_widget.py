"""The dock widget (kept importable here: ``from napari_aldic._widget import DICWidget``).

It lives in :mod:`napari_aldic._qt`, one panel per file.
"""

from ._qt import DICWidget

__all__ = ["DICWidget"]
