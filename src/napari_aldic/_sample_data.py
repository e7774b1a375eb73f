"""Sample data for napari (npe2 ``sample_data`` contributions).

Every function returns a list of layer-data tuples ``(data, kwargs, layer_type)``.
napari itself is never imported here: only NumPy, SciPy and the engine, so the
functions also work in scripts and tests.

* :func:`make_translation_pair` - synthetic speckle pair, sub-pixel translation
* :func:`make_crack_pair` - synthetic Mode-I crack, with the ROI as a Labels layer
* :func:`make_strain_sequence` - 5 frames of uniform strain growing 0 -> 2 %
* :func:`make_plate_with_hole` - Kirsch field around a hole, with its ROI
* :func:`load_open_hole_pair` - real open-hole tension images (CFRP coupon)
* :func:`load_crack_sequence` - real crack growing from a notch (6 frames, cropped)

The synthetic pairs carry their exact displacement in the layer ``metadata``
under ``"truth"``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .i18n import tr

__all__ = ["make_translation_pair", "make_crack_pair", "make_strain_sequence",
           "make_plate_with_hole", "load_open_hole_pair", "load_crack_sequence",
           "sample_data_dir", "open_hole_roi", "CRACK_FILE"]

#: translation of :func:`make_translation_pair`, pixels (u along x, v along y)
TRANSLATION = (0.45, -0.3)
OPEN_HOLE_FILES = ("oht_cfrp_00.tiff", "oht_cfrp_11.tiff")
CRACK_FILE = "crack_notch_crop.tif"


def make_translation_pair():
    """Synthetic 256 x 256 speckle pair whose second frame is translated by
    (u, v) = (+0.45, -0.30) px: a ``(2, 256, 256)`` uint8 stack."""
    from .engine import synthetic

    u, v = TRANSLATION
    ref, dfm = synthetic.speckle_pair((256, 256), synthetic.Translation(u, v), seed=3)
    stack = np.stack([ref, dfm])
    meta = {"truth": {"field": "translation", "u": u, "v": v},
            "description": "frame 0: reference; frame 1: rigid sub-pixel translation"}
    return [(stack, {"name": tr("speckle translation u={u:+.2f} v={v:+.2f} px").format(u=u, v=v),
                     "metadata": meta, "contrast_limits": (0, 255)}, "image")]


def make_crack_pair():
    """Synthetic 256 x 256 Mode-I crack pair (``(2, 256, 256)`` uint8 stack)
    and its ROI as a Labels layer (1 = analysed, 0 = the crack slot)."""
    from .engine.synthetic import make_case

    case = make_case("crack", (256, 256), seed=4, n_quad=2)
    f = case.field
    stack = np.stack([case.reference, case.deformed])
    meta = {"truth": {"field": "mode_I_crack", "tip": list(f.tip), "amplitude": f.amplitude,
                      "nu": f.nu, "t": list(f.t)},
            "description": case.description}
    labels = case.roi.astype(np.uint8)
    return [
        (stack, {"name": tr("speckle Mode-I crack"), "metadata": meta,
                 "contrast_limits": (0, 255)}, "image"),
        (labels, {"name": tr("ROI (crack excluded)"), "opacity": 0.3}, "labels"),
    ]


def make_strain_sequence(n_frames: int = 5, size: int = 256):
    """Synthetic ``(n_frames, size, size)`` uint8 sequence: uniform stretch
    along x growing linearly from 0 to 2 % (``eyy = -0.3 exx``) about the
    image centre, with a small drift."""
    from .engine import synthetic

    c = size / 2.0
    pat = synthetic.make_pattern((size, size), seed=11, margin=48)
    frames, truth = [], []
    for k in range(n_frames):
        e = 0.02 * k / max(1, n_frames - 1)
        t = (0.25 * k, -0.15 * k)
        field = synthetic.Affine.strain_rotation(exx=e, eyy=-0.3 * e, center=(c, c), t=t)
        frames.append(synthetic.render(pat, (size, size), None if k == 0 else field,
                                       n_quad=3, seed=20 + k))
        truth.append({"exx": e, "eyy": -0.3 * e, "center": [c, c], "t": list(t)})
    meta = {"truth": {"field": "uniform_strain", "frames": truth},
            "description": "uniform strain growing 0 -> 2 % over the frames"}
    return [(np.stack(frames), {"name": tr("speckle uniform strain sequence"), "metadata": meta,
                                "contrast_limits": (0, 255)}, "image")]


def make_plate_with_hole(size: int = 320):
    """Synthetic plate with a central hole under tension along x (Kirsch
    field, far-field exx ~ 0.9 %): a ``(2, size, size)`` uint8 stack and the
    ROI (outside the hole) as a Labels layer."""
    from .engine import synthetic

    c = size / 2.0
    field = synthetic.PlateWithHole(center=(c, c), radius=size / 8.0, amplitude=0.004,
                                    t=(0.3, -0.2))
    ref, dfm = synthetic.speckle_pair((size, size), field, seed=13, n_quad=3)
    meta = {"truth": {"field": "plate_with_hole", "center": [c, c], "radius": field.radius,
                      "amplitude": field.amplitude, "nu": field.nu, "t": list(field.t)},
            "description": "Kirsch field: plate with a hole under uniaxial tension (x)"}
    return [
        (np.stack([ref, dfm]), {"name": tr("speckle plate with hole"), "metadata": meta,
                                "contrast_limits": (0, 255)}, "image"),
        (field.roi((size, size)).astype(np.uint8),
         {"name": tr("ROI (hole excluded)"), "opacity": 0.3}, "labels"),
    ]


def sample_data_dir(name: str = "open_hole_tension", package_dir=None) -> Path:
    """Folder ``sample_data/<name>`` of the installed package or the source tree.

    A wheel holds it inside the package (``napari_aldic/sample_data``); an
    editable install leaves it at the top of the repository, two levels above
    the package folder.
    """
    pkg = Path(__file__).resolve().parent if package_dir is None else Path(package_dir)
    candidates = [pkg / "sample_data" / name, pkg.parent.parent / "sample_data" / name]
    for folder in candidates:
        if folder.is_dir():
            return folder
    raise FileNotFoundError(
        tr("sample data folder {name!r} not found (looked in {join}); "
           "reinstall napari-aldic").format(
               name=name, join=', '.join(str(c) for c in candidates)))


def open_hole_roi(image: np.ndarray, threshold: float = 40.0) -> np.ndarray:
    """Estimate the ROI of an open-hole coupon image: the bright speckled
    specimen, without the dark hole and background (True = analysed).

    The image is averaged over 15 x 15 pixel windows and thresholded, cleaned by
    a morphological opening, reduced to its largest connected region and
    eroded by 2 pixels to keep clear of the edges.
    """
    from scipy import ndimage

    smooth = ndimage.uniform_filter(np.asarray(image, np.float32), 15)
    mask = ndimage.binary_opening(smooth > threshold, iterations=3)
    lab, n = ndimage.label(mask)
    if n > 1:
        sizes = ndimage.sum_labels(mask, lab, index=np.arange(1, n + 1))
        mask = lab == 1 + int(np.argmax(sizes))
    return ndimage.binary_erosion(mask, iterations=2)


def load_open_hole_pair():
    """Real open-hole tension images of a CFRP coupon (1040 x 400, uint8):
    reference and loaded state as a ``(2, 1040, 400)`` stack, plus an
    estimated ROI (hole and background excluded) as a Labels layer.

    Images from the MATLAB AL-DIC repository (Jin Yang), BSD-3-Clause; see
    ``LICENSE-2D_ALDIC-data.txt`` beside them.
    """
    import tifffile

    folder = sample_data_dir("open_hole_tension")
    frames = [tifffile.imread(folder / name) for name in OPEN_HOLE_FILES]
    stack = np.stack(frames)
    meta = {"source": "2D_ALDIC (Jin Yang), BSD-3-Clause; see LICENSE-2D_ALDIC-data.txt",
            "files": [str(folder / name) for name in OPEN_HOLE_FILES]}
    roi = open_hole_roi(stack[0]).astype(np.uint8)
    return [
        (stack, {"name": tr("open-hole tension (CFRP)"), "metadata": meta,
                 "contrast_limits": (0, 255)}, "image"),
        (roi, {"name": tr("ROI (estimated, hole excluded)"), "opacity": 0.3}, "labels"),
    ]


def load_crack_sequence():
    """A real crack growing from a notch: 6 frames of 384 x 384 px (uint8),
    cropped from the 2D_ALDIC crack sequence (Jin Yang, BSD-3-Clause; see
    ``README.md`` and ``LICENSE-2D_ALDIC-data.txt`` beside the file).

    The specimen moves ~57 px upwards over the frames while the crack opens;
    the notch and the background (white, at the left) must be left out of the
    region of interest. The user guide walks through this analysis.
    """
    import tifffile

    path = sample_data_dir("crack_sequence") / CRACK_FILE
    stack = tifffile.imread(path)
    meta = {"source": str(path),
            "description": "crack growing from a notch; 2D_ALDIC (Jin Yang), BSD-3-Clause, "
                           "cropped and converted to 8 bits (see README.md beside the file)"}
    return [(stack, {"name": tr("crack from a notch (real)"), "metadata": meta,
                     "contrast_limits": (0, 255), "axis_labels": ("t", "y", "x")}, "image")]
