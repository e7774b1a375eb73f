"""napari-aldic: augmented Lagrangian digital image correlation for napari.

The analysis engine lives in :mod:`napari_aldic.engine` and never imports
napari or Qt; the napari side (sample data, widgets) builds on it.
"""

try:
    from importlib.metadata import version as _version

    __version__ = _version("napari-aldic")
except Exception:  # pragma: no cover - running from a source tree
    __version__ = "0.1.0"

__all__ = ["__version__"]
