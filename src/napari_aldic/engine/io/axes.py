"""Which axes of a stored image series are the frames of a 2-D DIC sequence.

A TIFF series (tifffile's ``series.axes``, e.g. ``"TCYX"`` for an ImageJ
hyperstack) or an OME-Zarr image (its ``multiscales`` axes) may hold more
than time: channels (C), focal planes (Z), samples (S). Flattening them into
frames would correlate channel 1 against channel 0 without a word, so
:func:`plan_frames` accepts one frame axis (T, or the generic page axes
I/Q of plain multi-page files, or Z when it is the only one) and a channel
axis only with an explicit ``channel`` choice; anything else is refused with
a message naming the axes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

__all__ = ["FramePlan", "plan_frames", "ChannelChoiceError"]

log = logging.getLogger("napari_aldic.io")

#: axis letters read as frames: time, and the generic page axes of tifffile
_FRAME = "TIQ"
#: axis letters that hold channels (S: samples stored in their own planes)
_CHANNEL = "CS"
_NAMES = {"T": "time", "C": "channel", "Z": "depth", "S": "sample", "I": "page",
          "Q": "page", "Y": "rows", "X": "columns"}


class ChannelChoiceError(ValueError):
    """A hyperstack's channel axis needs ``channel=N``; ``n_channels`` says how many."""

    def __init__(self, message: str, n_channels: int):
        super().__init__(message)
        self.n_channels = n_channels


@dataclass(frozen=True)
class FramePlan:
    """Where frame ``k`` lies in the leading (non-image) axes of a series."""

    lead: tuple  # shape of the leading axes
    frame_axis: int | None  # index in ``lead`` of the frame axis (None: one frame)
    channel_axis: int | None  # index in ``lead`` of the chosen channel axis
    channel: int | None
    n_frames: int
    axes: str

    def index(self, k: int) -> tuple:
        """The leading-axes index of frame ``k``."""
        idx = [0] * len(self.lead)
        if self.frame_axis is not None:
            idx[self.frame_axis] = k
        if self.channel_axis is not None:
            idx[self.channel_axis] = self.channel
        return tuple(idx)

    def page(self, k: int) -> int:
        """Frame ``k``'s position among the planes of the series, in storage order."""
        return int(np.ravel_multi_index(self.index(k), self.lead)) if self.lead else 0


def _sizes(axes: str, shape) -> str:
    return ", ".join(f"{a}={n}" for a, n in zip(axes, shape))


def plan_frames(shape, axes: str, n_image: int, name: str,
                channel: int | None = None) -> FramePlan:
    """The frames of a series of ``shape`` with ``axes`` letters whose last
    ``n_image`` axes are one image (YX, or YXS for colour).

    Raises
    ------
    ValueError
        Several frame-like axes (e.g. T and Z), a channel axis without a
        ``channel`` choice, a ``channel`` out of range or without a channel
        axis; the message names the file and its axes.
    """
    axes = str(axes).upper()
    lead, lead_axes = tuple(int(n) for n in shape[:-n_image]), axes[:-n_image]
    long = [(i, a) for i, (a, n) in enumerate(zip(lead_axes, lead)) if n > 1]
    chans = [i for i, a in long if a in _CHANNEL]
    frames = [i for i, a in long if a not in _CHANNEL]
    desc = f"{name} has axes {axes} ({_sizes(axes, shape)})"
    if len(chans) > 1:
        raise ValueError(f"{desc}: more than one channel axis; save one channel per stack")
    if chans and channel is None:
        i = chans[0]
        raise ChannelChoiceError(f"{desc}: a hyperstack with {lead[i]} channels "
                                 f"({lead_axes[i]}); choose one with --channel N (channel=N), "
                                 f"N from 0 to {lead[i] - 1}", lead[i])
    if channel is not None and not chans:
        raise ValueError(f"channel {channel} was chosen, but {desc} and no channel axis")
    if chans and not 0 <= channel < lead[chans[0]]:
        raise ValueError(f"channel {channel} is out of range: {desc}, channels 0 to "
                         f"{lead[chans[0]] - 1}")
    if len(frames) > 1:
        named = " and ".join(f"{lead_axes[i]} ({_NAMES.get(lead_axes[i], 'unknown')}, "
                             f"{lead[i]})" for i in frames)
        raise ValueError(f"{desc}: {named} are both frame-like; a 2-D sequence needs one "
                         "frame axis (save one Z position or one series per stack)")
    if frames and lead_axes[frames[0]] not in _FRAME + "Z":
        a = lead_axes[frames[0]]
        raise ValueError(f"{desc}: axis {a} ({_NAMES.get(a, 'unknown')}) is not a time axis; "
                         "a 2-D sequence needs its frames along T")
    if frames and lead_axes[frames[0]] == "Z":  # ImageJ saves plain stacks as slices too
        log.warning("%s: its Z axis (%d planes) is read as the frames of the sequence",
                    name, lead[frames[0]])
    f = frames[0] if frames else None
    return FramePlan(lead, f, chans[0] if chans else None, channel,
                     lead[f] if f is not None else 1, axes)
