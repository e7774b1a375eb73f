"""Accuracy of Local DIC and AL-DIC on noisy smooth fields, optionally beside pyALDIC.

Usage::

    python benchmarks/bench_accuracy.py [--pyaldic /work/pyaldic-venv/bin/python]
        [--seeds 31 32 33] [--noise 0 5 10]

Cases (256 x 256, 8-bit synthetic speckle, exact analytic truth, subset 31,
step 8; ``smooth_cases.py``): uniform strain plus a displacement wave,

* ``long_wave``: exx 0.5 %, eyy -0.2 %, u = 0.4 sin(2 pi x / 320),
  v = 0.3 sin(2 pi y / 320);
* ``short_wave``: exx 1 %, eyy -0.4 %, u = v = 0.5 sin(2 pi (x|y) / 128);

with Gaussian grey-level noise of the given standard deviations added to both
images. The RMSE of the displacement vector (px) is over the nodes valid in
every method (and, with pyALDIC, over our nodes interpolated at pyALDIC's:
its nodes sit on the same 8 px lattice offsets, so the comparison is per
node). Printed per case and noise level as the mean over seeds.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from smooth_cases import fields, pyaldic_run, write_rows


def rmse(x, y, u, v, field, sel) -> float:
    ut, vt = field.displacement(x, y)
    return float(np.sqrt(np.mean(((u - ut) ** 2 + (v - vt) ** 2)[sel])))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pyaldic", metavar="PYTHON")
    ap.add_argument("--seeds", type=int, nargs="+", default=[31, 32, 33])
    ap.add_argument("--noise", type=float, nargs="+", default=[0.0, 5.0, 10.0])
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)

    from napari_aldic.engine import correlate, synthetic as S

    rows = []
    for name, field in fields().items():
        for noise in args.noise:
            acc = {}
            for seed in args.seeds:
                ref, dfm = S.speckle_pair((256, 256), field, noise=noise, seed=seed)
                res = {"local": correlate(ref, dfm, method="local"),
                       "aldic": correlate(ref, dfm, method="aldic"),
                       "aldic_plain": correlate(ref, dfm, method="aldic", smooth=0.0,
                                                second_order_warp=False)}
                both = np.logical_and.reduce([r.valid for r in res.values()])
                for k, r in res.items():
                    acc.setdefault(k, []).append(rmse(r.x, r.y, r.u, r.v, field, both))
                acc.setdefault("smooth_px", []).append(
                    res["aldic"].meta["regularisation"]["smooth_px"])
                if args.pyaldic:
                    for m in ("local", "aldic"):
                        x, y, u, v = pyaldic_run(args.pyaldic, ref, dfm, 31, 8, m)
                        ok = np.isfinite(u) & np.isfinite(v)
                        acc.setdefault("pyaldic_" + m, []).append(
                            rmse(x, y, u, v, field, ok))
            row = {"case": name, "noise": noise, **{k: float(np.mean(v)) for k, v in acc.items()}}
            rows.append(row)
            line = (f"{name:10s} noise {noise:4.1f}: local {row['local']:.4f}  "
                    f"AL-DIC {row['aldic']:.4f} ({row['aldic'] / row['local'] - 1:+.1%})  "
                    f"plain Alg.1 {row['aldic_plain']:.4f} "
                    f"({row['aldic_plain'] / row['local'] - 1:+.1%})  "
                    f"smooth {row['smooth_px']:.1f} px")
            if args.pyaldic:
                line += (f"  | pyALDIC local {row['pyaldic_local']:.4f} AL-DIC "
                         f"{row['pyaldic_aldic']:.4f}")
            print(line, flush=True)
    return write_rows(rows, args.json)


if __name__ == "__main__":
    sys.exit(main())
