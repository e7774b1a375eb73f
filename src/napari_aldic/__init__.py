"""napari-aldic: augmented Lagrangian digital image correlation for napari.

The analysis engine lives in :mod:`napari_aldic.engine` and never imports
napari or Qt; the napari side (sample data, widgets) builds on it.
"""

try:
    from importlib.metadata import version as _version

    __version__ = _version("napari-aldic")
except Exception:  # pragma: no cover - running from a source tree
    __version__ = "0.1.0"

# the sample files the package ships (the crack sequence, the open-hole pair), for scripts
from ._sample_data import CRACK_FILE, sample_data_dir  # noqa: E402  (NumPy only, no napari)

__all__ = ["__version__", "CRACK_FILE", "sample_data_dir"]
