"""Files in and out: image stacks, run folders, result formats, settings files.

* :func:`open_stack` / :class:`FrameSource` / :func:`read_image` -- the one image and
  image-stack reader (arrays, multi-page TIFF, image folders, lists of image files)
  used by ``track``, the CLI and the napari reader; :func:`open_image` /
  :func:`open_lazy` -- one image read window by window (tiled TIFF, zarr, OME-Zarr);
  the pixel size and frame interval their metadata records (``FrameSource.units``);
* :func:`load_run`, :func:`collect_frames`, :func:`load_mat` -- results back from
  any file or folder the package writes;
* writers/readers per format: CSV, MATLAB, VTK (.vtu/.pvd), DaVis text;
* :func:`read_settings` / :func:`write_settings` (a :class:`~napari_aldic.engine.Settings`),
  :func:`read_settings` / :func:`write_settings` -- settings files.
"""

from ..core.files import available_memory, file_sha256, read_json_file, regular_file
from .axes import ChannelChoiceError
from .columns import FIELD_INFO, frame_columns
from .csv import export_csv, read_csv
from .davis import export_davis
from .matlab import export_mat
from .metadata import FrameInterval
from .runs import Frame, FrameSet, collect_frames, load_mat, load_run
from .settings_file import read_settings, write_settings
from .stack import (
    IMAGE_SUFFIXES,
    TIFF_SUFFIXES,
    FrameSource,
    grey_frame,
    image_files,
    natural_key,
    open_image,
    open_stack,
    read_image,
)
from .tiles import LazyImage, PixelSize, open_lazy, pixel_size_of
from .volumes import open_volume, read_volumes
from .vtk import export_vtu, read_vtu, result_cells

__all__ = [
    "FrameSource", "open_stack", "read_image", "image_files", "natural_key", "grey_frame",
    "IMAGE_SUFFIXES", "TIFF_SUFFIXES", "open_image", "open_lazy", "LazyImage", "PixelSize",
    "pixel_size_of",
    "Frame", "FrameSet", "collect_frames", "load_run", "load_mat", "frame_columns", "FIELD_INFO",
    "export_csv", "read_csv", "export_mat", "export_vtu", "read_vtu", "result_cells",
    "export_davis", "read_settings", "write_settings", "regular_file", "read_json_file",
    "file_sha256", "available_memory",
    "read_volumes", "open_volume",
    "ChannelChoiceError", "FrameInterval",
]
