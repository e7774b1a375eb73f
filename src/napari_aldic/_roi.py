"""Layers -> engine inputs: ROI masks from Shapes/Labels layers, seeds from Points.

Only the public layer API is used (``data``, ``shape_type``, ``edge_width``,
``data_to_world``, ``world_to_data``); napari is not imported, so the
rasterisation can be tested with plain arrays.

Coordinates: napari data coordinates are ``(row, col)`` = ``(y, x)``; every
vertex is taken from its own layer through world coordinates into the pixel
grid of the analysed image, so layers with a different scale or offset still
land on the right pixels.
"""

from __future__ import annotations

import numpy as np

from .i18n import tr

__all__ = ["shape_mask", "shapes_masks", "labels_mask", "labels_fit", "points_xy",
           "to_image_pixels", "build_roi", "CUT_TYPES"]

#: open shapes (lines and paths) cut the ROI along their length: cracks
CUT_TYPES = ("line", "path")


def to_image_pixels(layer, image, coords: np.ndarray) -> np.ndarray:
    """``(N, 2)`` (row, col) pixel positions in ``image`` of ``layer``'s data ``coords``."""
    coords = np.atleast_2d(np.asarray(coords, float))
    out = np.empty((coords.shape[0], 2))
    for i, c in enumerate(coords):
        world = np.asarray(layer.data_to_world(c), float)
        out[i] = np.asarray(image.world_to_data(world), float)[-2:]
    return out


def shape_mask(shape_type: str, rc: np.ndarray, image_shape, width: float = 1.0) -> np.ndarray:
    """Boolean mask of one shape given by its (row, col) vertices in pixels.

    Rectangles and polygons are filled polygons; an ellipse is given (as in
    napari) by the four corners of its bounding box, possibly rotated; a line
    or path is a band ``width`` pixels wide along it (at least one pixel).
    """
    from skimage.draw import polygon2mask

    h, w = int(image_shape[0]), int(image_shape[1])
    rc = np.asarray(rc, float)
    if shape_type in ("rectangle", "polygon"):
        return polygon2mask((h, w), rc)
    if shape_type == "ellipse":
        c = rc.mean(axis=0)
        a = (rc[1] - rc[0]) / 2.0  # half-axis vectors of the bounding box
        b = (rc[3] - rc[0]) / 2.0
        out = np.zeros((h, w), bool)
        na, nb = a @ a, b @ b
        if na <= 0 or nb <= 0:
            return out
        # evaluate only inside the (clipped) bounding box of the corners
        r0, c0 = np.maximum(np.floor(rc.min(axis=0)).astype(int), 0)
        r1, c1 = np.minimum(np.ceil(rc.max(axis=0)).astype(int) + 1, (h, w))
        if r1 <= r0 or c1 <= c0:
            return out
        rr, cc = np.mgrid[r0:r1, c0:c1]
        d = np.stack([rr - c[0], cc - c[1]], -1)
        out[r0:r1, c0:c1] = (d @ a / na) ** 2 + (d @ b / nb) ** 2 <= 1.0
        return out
    if shape_type in CUT_TYPES:
        from skimage.draw import line

        out = np.zeros((h, w), bool)
        pts = np.rint(rc).astype(np.int64)
        for p, q in zip(pts[:-1], pts[1:]):
            r, c = line(int(p[0]), int(p[1]), int(q[0]), int(q[1]))
            ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
            out[r[ok], c[ok]] = True
        half = max(0, int(round((float(width) - 1.0) / 2.0)))
        if half and out.any():
            from scipy import ndimage

            out = ndimage.binary_dilation(out, iterations=half)
        return out
    raise ValueError(tr("shape type {shape_type!r} cannot be turned into a region").format(
                            shape_type=shape_type))


def shapes_masks(layer, image, image_shape) -> tuple[np.ndarray, np.ndarray]:
    """``(areas, cuts)``: union of the closed shapes and of the lines/paths of ``layer``."""
    h, w = image_shape
    areas = np.zeros((h, w), bool)
    cuts = np.zeros((h, w), bool)
    widths = np.broadcast_to(np.asarray(getattr(layer, "edge_width", 1.0), float),
                             (len(layer.data),))
    for verts, kind, width in zip(layer.data, layer.shape_type, widths):
        rc = to_image_pixels(layer, image, verts)
        m = shape_mask(kind, rc, (h, w), width)
        if kind in CUT_TYPES:
            cuts |= m
        else:
            areas |= m
    return areas, cuts


def _plane(layer, frame: int) -> np.ndarray:
    """The 2-D plane of a Labels layer's data (frame ``frame`` of a 3-D stack)."""
    data = layer.data
    if getattr(layer, "multiscale", False):
        data = data[0]
    if data.ndim == 3:
        return np.asarray(data[min(frame, data.shape[0] - 1)])
    if data.ndim != 2:
        raise ValueError(tr("labels layer '{layer_name}' has {ndim} axes; use a 2-D one").format(
                                layer_name=layer.name, ndim=data.ndim))
    return np.asarray(data)


def _same_grid(layer, image, shape, image_shape) -> bool:
    """Whether the labels' pixels are the image's pixels (same size and placement)."""
    return (tuple(shape) == tuple(image_shape)
            and np.allclose(np.asarray(layer.scale)[-2:], np.asarray(image.scale)[-2:])
            and np.allclose(np.asarray(layer.translate)[-2:],
                            np.asarray(image.translate)[-2:]))


def _through_world(layer, image, plane: np.ndarray, image_shape, frame: int) -> np.ndarray:
    """``plane`` (labels pixels) sampled at every image pixel through world
    coordinates (nearest labels pixel; 0 outside the labels)."""
    h, w = int(image_shape[0]), int(image_shape[1])
    lead = [float(frame)] * (image.ndim - 2)
    corners = [np.asarray(layer.world_to_data(image.data_to_world([*lead, r, c])),
                          float)[-2:] for r, c in ((0, 0), (1, 0), (0, 1))]
    o, dr, dc = corners[0], corners[1] - corners[0], corners[2] - corners[0]
    rr, cc = np.mgrid[0:h, 0:w].astype(float)  # the map is affine: 3 points give it
    lr = np.rint(o[0] + rr * dr[0] + cc * dc[0]).astype(np.int64)
    lc = np.rint(o[1] + rr * dr[1] + cc * dc[1]).astype(np.int64)
    inside = (lr >= 0) & (lr < plane.shape[0]) & (lc >= 0) & (lc < plane.shape[1])
    out = np.zeros((h, w), bool)
    out[inside] = plane[lr[inside], lc[inside]] != 0
    return out


def labels_fit(layer, image) -> bool:
    """Whether a Labels layer covers exactly the pixels of the image layer
    ``image`` (same frame size, scale and offset): made for that image."""
    data = layer.data[0] if getattr(layer, "multiscale", False) else layer.data
    img = image.data[0] if getattr(image, "multiscale", False) else image.data
    return _same_grid(layer, image, tuple(data.shape[-2:]), tuple(img.shape[-2:]))


def labels_mask(layer, image_shape, frame: int = 0, image=None) -> np.ndarray:
    """Nonzero pixels of a Labels layer on the image's pixel grid (a 3-D labels
    stack gives its slice ``frame``).

    With the image layer ``image`` the labels are matched to it through world
    coordinates, so a labels layer of another size or offset (e.g. napari's
    'New labels layer' made while a Shapes layer was active) still lands on the
    right pixels; without it the labels must have the image's size.
    """
    plane = _plane(layer, frame)
    if image is not None and not _same_grid(layer, image, plane.shape, image_shape):
        return _through_world(layer, image, plane, image_shape, frame)
    if tuple(plane.shape) != tuple(image_shape):
        raise ValueError(tr("labels layer '{layer_name}' is {rows} x {cols} px but the image "
                            "is {image_rows} x {image_cols} px").format(
                                layer_name=layer.name, rows=plane.shape[0], cols=plane.shape[1],
                                image_rows=image_shape[0], image_cols=image_shape[1]))
    return plane != 0


def points_xy(layer, image) -> np.ndarray:
    """``(N, 2)`` seed positions ``(x, y)`` in image pixels (napari points are
    ``(..., row, col)``)."""
    if len(layer.data) == 0:
        return np.zeros((0, 2))
    rc = to_image_pixels(layer, image, np.asarray(layer.data, float))
    return rc[:, ::-1].copy()


def build_roi(image, image_shape, add_shapes=(), subtract_shapes=(), labels=None,
              frame: int = 0) -> tuple[np.ndarray | None, list[str]]:
    """The analysis ROI (True = analysed) and a note per input used.

    ``(union of the closed shapes of add_shapes, or the whole image) AND
    (nonzero labels, if given) AND NOT (closed shapes of subtract_shapes)``;
    lines and paths in any of the Shapes layers cut the ROI (cracks).
    Returns ``None`` when no layer restricts the analysis (whole image).
    """
    h, w = image_shape
    notes = []
    roi = np.ones((h, w), bool)
    restricted = False
    cut = np.zeros((h, w), bool)
    added = np.zeros((h, w), bool)
    any_add = False
    for layer in add_shapes:
        a, c = shapes_masks(layer, image, (h, w))
        cut |= c
        # drawn areas restrict the ROI even where they miss the image (then it is empty)
        any_add = any_add or any(k not in CUT_TYPES for k in layer.shape_type)
        added |= a
        notes.append(tr("+ shapes '{layer_name}' ({n_data} shapes)").format(
                            layer_name=layer.name, n_data=len(layer.data)))
    if any_add:
        roi &= added
        restricted = True
    if labels is not None:
        roi &= labels_mask(labels, (h, w), frame, image)
        restricted = True
        notes.append(tr("& labels '{labels_name}' (nonzero)").format(labels_name=labels.name))
    for layer in subtract_shapes:
        a, c = shapes_masks(layer, image, (h, w))
        roi &= ~a
        cut |= c
        restricted = restricted or bool(a.any())
        notes.append(tr("- shapes '{layer_name}' ({n_data} shapes)").format(
                            layer_name=layer.name, n_data=len(layer.data)))
    if cut.any():
        roi &= ~cut
        restricted = True
        notes.append(tr("cracks cut along lines/paths ({sum} px)").format(sum=int(cut.sum())))
    return (roi if restricted else None), notes
