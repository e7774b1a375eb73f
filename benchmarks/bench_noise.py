"""Local DIC under grey-level noise: napari-aldic beside pyALDIC, same nodes.

Usage::

    python benchmarks/bench_noise.py [--pyaldic /work/pyaldic-venv/bin/python]
        [--seeds 1 2 3] [--noise 0 2 5 10] [--subsets 21 31] [--cache DIR]
        [--interpolation auto] [--json OUT]

Cases (256 x 256, 8-bit synthetic speckle with exact analytic truth, step 8,
Local DIC only): the smooth fields of ``smooth_cases.py`` (``long_wave``:
uniform strain plus a 320 px displacement wave; ``short_wave``: 128 px wave),
with independent Gaussian noise of the given standard deviation (grey
levels) in both images.

The RMSE of the displacement vector (px) is taken over the nodes that both
programs place at the same pixel and both solve: pyALDIC's nodes sit at
``winsize/2 + 1 + 8k`` (subset 21) or ``winsize/2 + 8k`` (31) and ours at
``h + 1 + 8k``, so our images are cropped by the difference on the left and
top (the truth is shifted with them) to put our nodes on pyALDIC's. Printed
per case, noise and subset as the mean over seeds; pyALDIC results are cached
(``--cache``) because they do not change while our engine is tuned.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from smooth_cases import fields, pyaldic_run, write_rows

STEP = 8


def pyaldic_local(python: str, ref, dfm, subset: int, cache: Path | None, key: str):
    """pyALDIC's Local DIC on the pair: ``(x, y, u, v)`` (cached under ``key``)."""
    if cache is not None and (cache / f"{key}.npz").exists():
        p = np.load(cache / f"{key}.npz")
        return p["x"], p["y"], p["u"], p["v"]
    x, y, u, v = pyaldic_run(python, ref, dfm, subset, STEP, "local")
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        np.savez(cache / f"{key}.npz", x=x, y=y, u=u, v=v)
    return x, y, u, v


def ours_local(ref, dfm, subset: int, offset: int, **kw):
    """Our Local DIC with the nodes moved by ``offset`` px (crop): ``(x, y, u, v, valid)``
    in the coordinates of the uncropped images."""
    from napari_aldic.engine import correlate

    res = correlate(ref[offset:, offset:], dfm[offset:, offset:], subset=subset, step=STEP,
                    method="local", **kw)
    return res.x + offset, res.y + offset, res.u, res.v, res.valid


def common_rmse(field, ours, theirs=None):
    """RMSE (px) of ours and theirs over the nodes both solve at the same pixel."""
    x, y, u, v, valid = ours
    sel = valid.copy()
    if theirs is not None:
        px, py, pu, pv = theirs
        index = {(int(a), int(b)): i for i, (a, b) in enumerate(zip(px, py))}
        j = np.array([index.get((int(a), int(b)), -1) for a, b in zip(x, y)])
        sel &= j >= 0
        jj = np.where(j >= 0, j, 0)
        sel &= np.isfinite(pu[jj]) & np.isfinite(pv[jj])
    ut, vt = field.displacement(x.astype(float), y.astype(float))
    e_ours = float(np.sqrt(np.mean(((u - ut) ** 2 + (v - vt) ** 2)[sel])))
    if theirs is None:
        return e_ours, None, int(sel.sum())
    e_py = float(np.sqrt(np.mean(((pu[jj] - ut) ** 2 + (pv[jj] - vt) ** 2)[sel])))
    return e_ours, e_py, int(sel.sum())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pyaldic", metavar="PYTHON")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--noise", type=float, nargs="+", default=[0.0, 2.0, 5.0, 10.0])
    ap.add_argument("--subsets", type=int, nargs="+", default=[21, 31])
    ap.add_argument("--cases", nargs="+", default=list(fields()))
    ap.add_argument("--cache", type=Path, help="folder for pyALDIC results")
    ap.add_argument("--interpolation", default="auto")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)

    from napari_aldic.engine import synthetic as S

    rows = []
    for name in args.cases:
        field = fields()[name]
        for subset in args.subsets:
            for noise in args.noise:
                acc: dict[str, list] = {}
                for seed in args.seeds:
                    ref, dfm = S.speckle_pair((256, 256), field, noise=noise, seed=seed)
                    theirs, offset = None, 0
                    if args.pyaldic:
                        key = f"{name}_s{subset}_n{noise:g}_seed{seed}"
                        theirs = pyaldic_local(args.pyaldic, ref, dfm, subset, args.cache, key)
                        offset = int(theirs[0].min() - (subset // 2 + 1)) % STEP
                    ours = ours_local(ref, dfm, subset, offset,
                                      interpolation=args.interpolation)
                    e_ours, e_py, n = common_rmse(field, ours, theirs)
                    acc.setdefault("ours", []).append(e_ours)
                    acc.setdefault("nodes", []).append(n)
                    if e_py is not None:
                        acc.setdefault("pyaldic", []).append(e_py)
                row = {"case": name, "subset": subset, "noise": noise,
                       **{k: float(np.mean(v)) for k, v in acc.items()}}
                rows.append(row)
                line = (f"{name:10s} subset {subset} noise {noise:4.1f}: ours {row['ours']:.4f}"
                        f"  ({row['nodes']:.0f} nodes)")
                if "pyaldic" in row:
                    line += (f"  pyALDIC {row['pyaldic']:.4f}  "
                             f"ratio {row['ours'] / row['pyaldic']:.3f}")
                print(line, flush=True)
    return write_rows(rows, args.json)


if __name__ == "__main__":
    sys.exit(main())
