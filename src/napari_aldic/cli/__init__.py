"""Command line interface: ``napari-aldic demo``, ``run``, ``export`` and ``params``.

``demo`` renders a synthetic speckle pair with exact truth, analyses it and
reports the error; ``run`` analyses an image pair, a multi-page TIFF stack or a
folder of images (frame 0 is the reference; every other frame is correlated
against it) and writes one ``.npz`` result per frame; ``export`` turns results
(a ``.npz``, several, or a run folder) into MATLAB, CSV, VTK, DaVis text,
PNG/GIF/MP4 images and a PDF report; ``params`` writes a settings file.

Errors in the input (missing or unreadable files, bad parameters, images the
engine rejects) print ``napari-aldic: error: <message>`` and exit with code 2.

Modules: :mod:`.parser` (the argument parser), :mod:`.app` (``main``), one
module per command (:mod:`.demo`, :mod:`.run`, :mod:`.params`, :mod:`.export`),
:mod:`.settings` (settings file + options) and :mod:`.console` (output). The
CLI uses the engine's public API only.
"""

from .app import main
from .parser import build_parser

__all__ = ["main", "build_parser"]
