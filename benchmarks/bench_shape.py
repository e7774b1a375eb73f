"""Affine vs quadratic (second-order) subsets of Local DIC, side by side.

Usage::

    python benchmarks/bench_shape.py [--subsets 21 31] [--noise 2] [--seed 1]
        [--repeat 3] [--json OUT]

Three figures per subset width, all from synthetic 8-bit speckle with exact
analytic truth (Local DIC, step 4):

* **spatial resolution** -- a star-type field (DIC Challenge 2.0 style),
  ``v = A cos(2 pi y / p(x))`` with ``A = 0.5`` px and a period ``p`` growing
  linearly from 6 px to 150 px along x (256 x 768 px, no noise). Per column
  band the measured amplitude is the least-squares factor between measured
  and true ``v``; the *10 % amplitude-loss period* is the longest period at
  which that factor falls below 0.9 (smaller is better);
* **noise** -- a static pair (zero displacement, independent Gaussian noise
  of ``--noise`` grey levels in both images): the standard deviation of
  ``u`` and ``v`` over the valid nodes;
* **speed** -- POI/s of the whole ``correlate`` call on the static pair,
  affine and quadratic interleaved ``--repeat`` times after a warm-up (the
  machine is shared: the ratio, measured side by side, is the figure).

With ``--wider N`` the quadratic subset is also run ``N`` px wider than the
affine one (a quadratic fit's intercept is ~1.9x noisier on the same subset,
so a fair trade compares resolution at equal noise).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

STEP = 4
SHAPE = (256, 768)


def star_field(width: int = SHAPE[1], amplitude: float = 0.5, p0: float = 6.0,
               p1: float = 150.0):
    """``v = A cos(2 pi y / p(x))`` with ``p`` linear from ``p0`` to ``p1`` along x."""
    from napari_aldic.engine import synthetic as S

    class Star(S.DisplacementField):
        def period(self, X):
            return p0 + (p1 - p0) * np.asarray(X, float) / width

        def displacement(self, X, Y):
            X = np.asarray(X, float)
            return np.zeros_like(X), amplitude * np.cos(2 * np.pi * np.asarray(Y) /
                                                        self.period(X))

    return Star()


def loss_period(res, field, band: int = 16) -> tuple[float, list]:
    """Longest period whose measured amplitude is below 90 % of the truth, and
    the ``(period, amplitude ratio)`` profile over column bands."""
    _, vt = field.displacement(res.x.astype(float), res.y.astype(float))
    prof = []
    for x0 in range(0, SHAPE[1], band):
        sel = res.valid & (res.x >= x0) & (res.x < x0 + band)
        if sel.sum() < 8:
            continue
        ratio = float(np.sum(res.v[sel] * vt[sel]) / np.sum(vt[sel] ** 2))
        prof.append((float(field.period(x0 + band / 2)), ratio))
    lost = [p for p, r in prof if r < 0.9]
    return (max(lost) if lost else float("nan")), prof


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--subsets", type=int, nargs="+", default=[21, 31])
    ap.add_argument("--noise", type=float, default=2.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--wider", type=int, default=0)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)

    from napari_aldic.engine import correlate, synthetic as S

    star = star_field()
    ref, dfm = S.speckle_pair(SHAPE, star, seed=args.seed)
    sref, sdfm = S.speckle_pair(SHAPE, S.Translation(0.0, 0.0), noise=args.noise,
                                seed=args.seed + 10)
    rows = []
    for subset in args.subsets:
        row: dict = {"subset": subset}
        for shape in ("affine", "quadratic"):
            res = correlate(ref, dfm, subset=subset, step=STEP, shape_function=shape)
            row[f"{shape}_loss_period_px"], row[f"{shape}_profile"] = loss_period(res, star)
            stat = correlate(sref, sdfm, subset=subset, step=STEP, shape_function=shape)
            row[f"{shape}_noise_px"] = float(np.sqrt(0.5 * (np.var(stat.u[stat.valid])
                                                            + np.var(stat.v[stat.valid]))))
        if args.wider:
            wide = subset + args.wider
            res = correlate(ref, dfm, subset=wide, step=STEP, shape_function="quadratic")
            row["wider_subset"] = wide
            row["wider_loss_period_px"], _ = loss_period(res, star)
            stat = correlate(sref, sdfm, subset=wide, step=STEP, shape_function="quadratic")
            row["wider_noise_px"] = float(np.sqrt(0.5 * (np.var(stat.u[stat.valid])
                                                         + np.var(stat.v[stat.valid]))))
            print(f"subset {subset}: quadratic at {wide} px: loss period "
                  f"{row['wider_loss_period_px']:.1f} px (ratio "
                  f"{row['wider_loss_period_px'] / row['affine_loss_period_px']:.2f} of affine "
                  f"at {subset}), noise {row['wider_noise_px']:.4f} px (ratio "
                  f"{row['wider_noise_px'] / row['affine_noise_px']:.2f})", flush=True)
        times = {"affine": [], "quadratic": []}
        for _ in range(args.repeat):
            for shape in times:
                t = time.perf_counter()
                stat = correlate(sref, sdfm, subset=subset, step=STEP, shape_function=shape)
                times[shape].append(stat.x.size / (time.perf_counter() - t))
        for shape, v in times.items():
            row[f"{shape}_poi_per_s"] = float(np.median(v))
        rows.append(row)
        print(f"subset {subset}: 10% loss period affine {row['affine_loss_period_px']:.1f} px, "
              f"quadratic {row['quadratic_loss_period_px']:.1f} px (ratio "
              f"{row['quadratic_loss_period_px'] / row['affine_loss_period_px']:.2f}); noise "
              f"affine {row['affine_noise_px']:.4f} px, quadratic {row['quadratic_noise_px']:.4f}"
              f" px (ratio {row['quadratic_noise_px'] / row['affine_noise_px']:.2f}); POI/s "
              f"affine {row['affine_poi_per_s']:.0f}, quadratic {row['quadratic_poi_per_s']:.0f}"
              f" (ratio {row['quadratic_poi_per_s'] / row['affine_poi_per_s']:.2f})", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
