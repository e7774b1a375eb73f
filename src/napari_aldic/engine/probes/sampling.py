"""Values of node fields at arbitrary reference points, each with a status.

A point is sampled from the trusted nodes around it:

1. inside a mesh cell whose four corners hold trusted values: bilinear (Q4)
   interpolation, status ``ok``;
2. otherwise (next to a crack, a hole, the ROI edge or untrusted nodes): a
   least-squares plane through the nearest trusted nodes (up to six, within 2.5
   node spacings) that the point *sees inside the ROI* -- a node on the other
   side of a crack never enters. ``ok`` when the nearest of them is within one
   node spacing, ``degraded`` (extrapolated) beyond;
3. otherwise ``missing``, with the reason: outside the image, outside the ROI,
   the material left the field of view, too few trusted nodes (and why the
   others are not trusted).

A missing value is NaN, never 0.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from ..core.reasons import Reason
from ..io.vtk import result_cells
from ..viz.report import sample_cells

__all__ = ["OK", "DEGRADED", "MISSING", "STATUS_NAMES", "Sampled", "FrameSampler",
           "segment_in_roi", "worst"]

OK, DEGRADED, MISSING = 0, 1, 2
#: status code -> word written in tables and CSV files
STATUS_NAMES = ("ok", "degraded", "missing")
#: nodes of a plane fit: at most this many, within FIT_RADIUS node spacings
FIT_NODES = 6
FIT_RADIUS = 2.5


@dataclass
class Sampled:
    """Sampled values with their status code and reason (``""`` when ok)."""

    values: np.ndarray
    status: np.ndarray
    reasons: list


def worst(*parts: Sampled) -> tuple[np.ndarray, list]:
    """Element-wise worst status of several samplings and their reasons joined."""
    status = np.max([p.status for p in parts], axis=0)
    reasons = []
    for i in range(status.size):
        texts = [p.reasons[i] for p in parts if p.reasons[i]]
        reasons.append("; ".join(dict.fromkeys(texts)))
    return status, reasons


def segment_in_roi(roi: np.ndarray | None, x0, y0, x1, y1, spacing: float = 0.5) -> bool:
    """True when the straight segment stays on ROI pixels (nearest pixel every
    ``spacing`` px); always True without a ROI."""
    if roi is None:
        return True
    n = max(2, int(np.ceil(np.hypot(x1 - x0, y1 - y0) / spacing)) + 1)
    t = np.linspace(0.0, 1.0, n)
    cols = np.clip(np.rint(x0 + t * (x1 - x0)).astype(int), 0, roi.shape[1] - 1)
    rows = np.clip(np.rint(y0 + t * (y1 - y0)).astype(int), 0, roi.shape[0] - 1)
    return bool(roi[rows, cols].all())


class FrameSampler:
    """Samples node fields of one result at reference points.

    ``cells`` (the result's Q4 cells) and the node search tree depend only on the
    nodes and the ROI: pass ``like=`` a sampler of another frame with the same
    nodes to reuse them.
    """

    def __init__(self, result, like: FrameSampler | None = None):
        from scipy.spatial import cKDTree

        self.result = result
        self.x = np.asarray(result.x, float)
        self.y = np.asarray(result.y, float)
        self.roi = None if result.roi is None else np.asarray(result.roi, bool)
        self.shape = tuple(int(s) for s in result.image_shape)
        self.step = float(result.params.step)
        if like is not None and like.same_nodes(result):
            self.cells, self.tree = like.cells, like.tree
        else:
            self.cells = result_cells(result)
            self.tree = cKDTree(np.column_stack([self.x, self.y]))

    def same_nodes(self, result) -> bool:
        """Whether ``result`` has this sampler's nodes (and ROI)."""
        roi = None if result.roi is None else np.asarray(result.roi, bool)
        same_roi = (roi is None and self.roi is None) or (
            roi is not None and self.roi is not None and np.array_equal(roi, self.roi))
        return (len(result.x) == self.x.size and np.array_equal(result.x, self.x)
                and np.array_equal(result.y, self.y) and same_roi)

    # ------------------------------------------------------------ sampling
    def where_missing(self, px: float, py: float) -> str | None:
        """Why no value can exist at ``(px, py)`` whatever the field, else None."""
        rows, cols = self.shape
        if not (-0.5 <= px <= cols - 0.5 and -0.5 <= py <= rows - 0.5):
            return f"({px:.1f}, {py:.1f}) is outside the image ({cols} x {rows} px)"
        if self.roi is not None:
            r = min(max(int(round(py)), 0), rows - 1)
            c = min(max(int(round(px)), 0), cols - 1)
            if not self.roi[r, c]:
                return (f"({px:.1f}, {py:.1f}) is outside the ROI (crack, hole or background): "
                        "move it onto the material")
        return None

    def sample(self, values: np.ndarray, px, py) -> Sampled:
        """``values`` (one per node; untrusted nodes are ignored) at the points ``(px, py)``."""
        px = np.atleast_1d(np.asarray(px, float))
        py = np.atleast_1d(np.asarray(py, float))
        # untrusted nodes never contribute, whatever the caller passes
        values = np.where(np.asarray(self.result.valid, bool), np.asarray(values, float), np.nan)
        out = sample_cells(self.x, self.y, self.cells, values, px, py)
        status = np.where(np.isfinite(out), OK, MISSING).astype(np.int8)
        reasons = [""] * px.size
        for i in np.nonzero(status != OK)[0]:
            why = self.where_missing(px[i], py[i])
            if why is not None:
                out[i], reasons[i] = np.nan, why
                continue
            out[i], status[i], reasons[i] = self._fit(values, px[i], py[i])
        # a point outside the ROI inside a cell (a thin slot between nodes) has no material
        for i in np.nonzero(status == OK)[0]:
            why = self.where_missing(px[i], py[i])
            if why is not None:
                out[i], status[i], reasons[i] = np.nan, MISSING, why
        return Sampled(out, status, reasons)

    def _visible(self, px: float, py: float, idx) -> list[int]:
        return [int(j) for j in idx
                if segment_in_roi(self.roi, px, py, self.x[j], self.y[j])]

    def _fit(self, values: np.ndarray, px: float, py: float) -> tuple[float, int, str]:
        """Plane through the nearest trusted visible nodes: (value, status, reason)."""
        near = self.tree.query_ball_point([px, py], r=FIT_RADIUS * self.step)
        near = self._visible(px, py, near)
        good = [j for j in near if np.isfinite(values[j])]
        flat = False
        if len(good) >= 3:
            d = np.hypot(self.x[good] - px, self.y[good] - py)
            keep = np.asarray(good)[np.argsort(d)[:FIT_NODES]]
            A = np.column_stack([np.ones(keep.size), self.x[keep] - px, self.y[keep] - py])
            if np.linalg.matrix_rank(A, tol=1e-6 * self.step) == 3:
                coef = np.linalg.lstsq(A, values[keep], rcond=None)[0]
                dmin = float(d.min())
                if dmin <= self.step:
                    return float(coef[0]), OK, ""
                return (float(coef[0]), DEGRADED,
                        f"extrapolated {dmin:.1f} px from the nearest trusted node")
            flat = True
        if flat:
            return (np.nan, MISSING, f"the {len(good)} trusted nodes near the point lie on one "
                    "line: no plane through them")
        return np.nan, MISSING, self._why_too_few(near, good)

    def _why_too_few(self, near: list[int], good: list[int]) -> str:
        if not near:
            return (f"no node within {FIT_RADIUS:g} node spacings that the point sees "
                    "inside the ROI (outside the measured field)")
        bad = [j for j in near if j not in set(good)]
        codes = Counter(int(self.result.reason[j]) for j in bad)
        codes.pop(int(Reason.OK), None)
        if codes.get(int(Reason.OUT_OF_IMAGE), 0) >= max(codes.values(), default=0) > 0:
            return ("the point left the field of view (its nodes' deformed subsets leave "
                    "the image)")
        if codes:
            top = ", ".join(f"{Reason.describe(c)}: {n}" for c, n in codes.most_common(2))
            return (f"too few trusted nodes around the point ({len(good)} of {len(near)}; "
                    f"untrusted: {top})")
        if len(bad) == 0:
            return (f"only {len(good)} node(s) within {FIT_RADIUS:g} node spacings: the point "
                    "is outside the measured field")
        return (f"too few nodes with a value around the point ({len(good)} of {len(near)}; "
                "the field is not defined there, e.g. strain at the ROI edge)")
