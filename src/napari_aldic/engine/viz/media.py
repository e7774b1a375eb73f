"""PNG, GIF and MP4 renderings of field maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.files import (
    AtomicFiles,
    EncoderNotFoundError,
    ExportError,
    atomic_write,
    numbered_path,
    target_path,
)
from .figures import FieldSeries, frame_figure, prepare_series

__all__ = ["export_png", "export_gif", "export_mp4", "render_rgb", "series_rgb"]


def render_rgb(fig, dpi: int) -> np.ndarray:
    """The figure drawn at ``dpi`` as an RGB array (H, W, 3) of uint8."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    fig.set_dpi(dpi)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def export_png(data, path, field: str = "u", *, frames=None, units=None, strain=True,
               image=None, cmap=None, clim=None, dpi: int = 150) -> list[Path]:
    """PNG image(s) of one field with a colour bar labelled with its unit.

    One frame writes ``path``; several write ``STEM_frame#####.png`` each,
    all with the same colour limits (``clim`` or robust limits over the
    frames). Returns the paths written.
    """
    path = target_path(path, (".png",))
    series = prepare_series(data, field, frames, units, strain, clim)
    fr_list = series.frames
    targets = [path] if len(fr_list) == 1 else [numbered_path(path, fr.index) for fr in fr_list]
    written = []
    with AtomicFiles() as files:  # a frame series appears whole or not at all
        for fr, target in zip(fr_list, targets):
            fig = frame_figure(series, fr, image=image, cmap=cmap)
            with files.write(target) as tmp:
                fig.savefig(tmp, format="png", dpi=dpi)
            written.append(target)
    return written


def series_rgb(series: FieldSeries, image, cmap, dpi: int):
    """RGB pictures (H, W, 3) of every frame of ``series``, one at a time."""
    for fr in series.frames:
        yield render_rgb(frame_figure(series, fr, image=image, cmap=cmap), dpi)


def export_gif(data, path, field: str = "u", *, frames=None, units=None, strain=True,
               fps: float = 4.0, image=None, cmap=None, clim=None, dpi: int = 100,
               loop: int = 0) -> Path:
    """Animated GIF of one field over the frames (Pillow), fixed colour limits.

    One GIF frame per result frame, ``1/fps`` seconds each; ``loop=0``
    repeats forever.
    """
    from PIL import Image

    if not fps > 0:
        raise ValueError(f"fps={fps!r} must be > 0")
    path = target_path(path, (".gif",))
    series = prepare_series(data, field, frames, units, strain, clim)
    images = [Image.fromarray(rgb).quantize(colors=256, method=Image.Quantize.MEDIANCUT,
                                            dither=Image.Dither.NONE)
              for rgb in series_rgb(series, image, cmap, dpi)]
    with atomic_write(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                       duration=int(round(1000 / fps)), loop=loop, optimize=False,
                       disposal=1)
    return path


def _ffmpeg():
    """The ``imageio_ffmpeg`` module with a working ffmpeg, or a clear error."""
    hint = ("MP4 export needs the ffmpeg encoder from the 'imageio-ffmpeg' package: install "
            "it with  pip install imageio-ffmpeg  (or  pip install 'napari-aldic[video]'). "
            "Animated GIF export works without it (use the .gif format)")
    try:
        import imageio_ffmpeg
    except ImportError:
        raise EncoderNotFoundError(hint) from None
    try:
        imageio_ffmpeg.get_ffmpeg_exe()
    except Exception as exc:  # RuntimeError when no binary is found
        raise EncoderNotFoundError(f"{hint} ({exc})") from None
    return imageio_ffmpeg


def export_mp4(data, path, field: str = "u", *, frames=None, units=None, strain=True,
               fps: float = 4.0, image=None, cmap=None, clim=None, dpi: int = 100,
               quality: float = 8) -> Path:
    """MP4 video (H.264 via ``imageio-ffmpeg``) of one field over the frames.

    Raises :class:`EncoderNotFoundError` with install advice when ffmpeg is
    missing (GIF export still works then).
    """
    if not fps > 0:
        raise ValueError(f"fps={fps!r} must be > 0")
    path = target_path(path, (".mp4",))
    ffmpeg = _ffmpeg()
    series = prepare_series(data, field, frames, units, strain, clim)
    rgbs = list(series_rgb(series, image, cmap, dpi))
    h, w = rgbs[0].shape[:2]
    H, W = -(-h // 16) * 16, -(-w // 16) * 16  # pad to whole macro blocks (no rescaling)
    with atomic_write(path) as tmp:
        writer = ffmpeg.write_frames(str(tmp), (W, H), fps=fps, codec="libx264",
                                     quality=quality, macro_block_size=1,
                                     ffmpeg_log_level="error",
                                     output_params=["-f", "mp4"])
        try:
            writer.send(None)
            for rgb in rgbs:
                frame = np.full((H, W, 3), 255, np.uint8)
                frame[:h, :w] = rgb
                writer.send(np.ascontiguousarray(frame))
        except BaseException:
            try:
                writer.close()
            except Exception:
                pass
            raise
        try:
            writer.close()  # waits for ffmpeg to finish the file
        except RuntimeError as exc:
            raise ExportError(f"cannot write {path}: the video encoder failed ({exc}). "
                              "Check the free disk space, or export a GIF instead",
                              path) from exc
    return path


