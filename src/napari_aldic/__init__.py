"""napari-aldic: augmented Lagrangian digital image correlation for napari.

The analysis engine lives in :mod:`napari_aldic.engine` and never imports
napari or Qt; the napari side (sample data, widgets) builds on it.
"""

try:
    from importlib.metadata import version as _version

    __version__ = _version("napari-aldic")
except Exception:  # pragma: no cover - running from a source tree
    __version__ = "0.1.0"

__all__ = ["__version__", "CRACK_FILE", "sample_data_dir"]


def __getattr__(name: str):
    # the sample files the package ships (crack sequence, open-hole pair), for
    # scripts; imported on first use so that importing the engine stays lean
    if name in ("CRACK_FILE", "sample_data_dir"):
        from . import _sample_data

        return getattr(_sample_data, name)
    raise AttributeError(f"module 'napari_aldic' has no attribute {name!r}")
