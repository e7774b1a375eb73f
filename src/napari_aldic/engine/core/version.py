"""The installed package version, read from the distribution metadata.

The engine records it in every result; reading it here (not from
``napari_aldic.__version__``) keeps the engine from importing its parent package.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("napari-aldic")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
