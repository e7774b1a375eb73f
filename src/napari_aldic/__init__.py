"""napari-aldic: augmented Lagrangian digital image correlation for napari.

The analysis engine lives in :mod:`napari_aldic.engine` and never imports
napari or Qt; the napari side (sample data, widgets) builds on it.
"""

__all__ = ["__version__", "CRACK_FILE", "sample_data_dir"]


def _installed_version() -> str:
    try:
        from importlib.metadata import version

        return version("napari-aldic")
    except Exception:  # pragma: no cover - running from a source tree
        return "0.1.0"


def __getattr__(name: str):
    # the version is looked up on first use: importlib.metadata takes a
    # noticeable part of the command line's start-up
    if name == "__version__":
        globals()["__version__"] = value = _installed_version()
        return value
    # the sample files the package ships (crack sequence, open-hole pair), for
    # scripts; imported on first use so that importing the engine stays lean
    if name in ("CRACK_FILE", "sample_data_dir"):
        from . import _sample_data

        return getattr(_sample_data, name)
    raise AttributeError(f"module 'napari_aldic' has no attribute {name!r}")
