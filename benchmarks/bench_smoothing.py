"""AL-DIC's automatic smoothing on fields with detail, and the global solver.

Two benchmarks (issue 12 point 2, issue 13 section 2):

``accuracy``: u and v RMSE (px, against the exact field) of Local DIC and
AL-DIC, side by side with pyALDIC when its venv is given, on synthetic
speckle pairs: a DIC Challenge 1.0 Sample 14 type field (a 0.1 px sine whose
period shrinks along x to 2 subsets), a fine sine of period 2 subsets
everywhere, a Mode-I crack (ROI slot along the crack), a plate with a hole,
and two smooth fields (where AL-DIC's smoothing should pay), at several
noise levels and seeds. Local and AL-DIC are compared on the same nodes
(AL-DIC's valid nodes; its ``u_local`` is the Local DIC result).

``solver``: the AL-DIC global system on growing uniform meshes: SuperLU
factor vs Jacobi-CG vs AMG-CG (pyamg): setup time, solve time per ADMM
iteration, CG iterations, factor size. Timings are taken in one run,
interleaved, and are meant as ratios (a shared 2-core machine).

    python benchmarks/bench_smoothing.py accuracy [--seeds 3] [--noise 2 5 10]
        [--cases sample14 fine crack hole smooth_long smooth_short]
        [--pyaldic /work/pyaldic-venv/bin/python] [--json out.json]
    python benchmarks/bench_smoothing.py solver [--sizes 100 200 300] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from napari_aldic.engine import correlate, synthetic as S

HERE = Path(__file__).resolve().parent


@dataclass
class Chirp(S.DisplacementField):
    """``u = A sin(φ(x))`` whose local period shrinks geometrically from ``p0``
    at x = 0 to ``p1`` at x = ``width`` (DIC Challenge 1.0 Sample 14 type);
    ``v = 0``."""

    amplitude: float = 0.1
    p0: float = 300.0
    p1: float = 42.0
    width: float = 768.0

    def displacement(self, X, Y):
        X = np.asarray(X, float)
        a = np.log(self.p0 / self.p1) / self.width
        phase = 2 * np.pi / (self.p0 * a) * (np.exp(a * X) - 1)
        return self.amplitude * np.sin(phase), np.zeros_like(np.asarray(Y, float) + X)


def case(name: str):
    """``(field, shape, roi, subset)`` of a named case."""
    if name == "sample14":
        return Chirp(width=768.0, p1=42.0), (192, 768), None, 21
    if name == "fine":
        return S.Sinusoid(0.1, 0.1, wavelength=62.0), (256, 256), None, 31
    if name == "crack":
        tip = (200.0, 128.0)
        return (S.ModeICrack(tip=tip, amplitude=0.08, t=(0.3, 0.2)), (256, 320),
                S.crack_roi((256, 320), tip), 21)
    if name == "hole":
        f = S.PlateWithHole(center=(160.0, 128.0), radius=32.0, amplitude=0.004, t=(0.2, -0.1))
        return f, (256, 320), f.roi((256, 320)), 21
    if name == "smooth_long":
        return (S.Sum([S.Affine.strain_rotation(exx=0.005, eyy=-0.002, center=(128, 128)),
                       S.Sinusoid(0.4, 0.3, wavelength=320.0)]), (256, 256), None, 31)
    if name == "smooth_short":
        return (S.Sum([S.Affine.strain_rotation(exx=0.01, eyy=-0.004, center=(128, 128)),
                       S.Sinusoid(0.5, 0.5, wavelength=128.0)]), (256, 256), None, 31)
    raise ValueError(f"unknown case {name!r}")


CASES = ("sample14", "fine", "crack", "hole", "smooth_long", "smooth_short")


def _rmse(x, y, u, v, field, sel):
    ut, vt = field.displacement(x, y)
    return (float(np.sqrt(np.mean((u - ut)[sel] ** 2))),
            float(np.sqrt(np.mean((v - vt)[sel] ** 2))))


def _pyaldic(python: str, ref, dfm, roi, subset: int, field):
    """pyALDIC AL-DIC ``(u, v)`` RMSE at its own finite nodes, or None."""
    import tifffile

    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        tifffile.imwrite(t / "r.tif", ref)
        tifffile.imwrite(t / "d.tif", dfm)
        cmd = [python, str(HERE / "pyaldic_runner.py"), str(t / "r.tif"), str(t / "d.tif"),
               "--subset", str(subset), "--step", "8", "--method", "aldic", "--repeat", "1",
               "--no-warmup", "--out", str(t / "o.npz")]
        if roi is not None:
            np.save(t / "m.npy", roi)
            cmd += ["--mask", str(t / "m.npy")]
        run = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
        if run.returncode != 0:
            print("  pyALDIC failed:", run.stderr.strip().splitlines()[-1:], file=sys.stderr)
            return None
        z = np.load(t / "o.npz")
        x, y, u, v = (np.asarray(z[k], float).ravel() for k in ("x", "y", "u", "v"))
    ok = np.isfinite(u) & np.isfinite(v)
    return _rmse(x, y, u, v, field, ok)


def accuracy(args) -> dict:
    out = {}
    for name in args.cases:
        field, shape, roi, subset = case(name)
        for noise in args.noise:
            rows = []
            for seed in range(args.seeds):
                ref, dfm = S.speckle_pair(shape, field, noise=noise, seed=100 + seed, n_quad=3)
                al = correlate(ref, dfm, roi=roi, subset=subset, step=8, method="aldic")
                sel = al.valid & np.isfinite(al.u_local) & np.isfinite(al.v_local)
                row = {"local": _rmse(al.x, al.y, al.u_local, al.v_local, field, sel),
                       "aldic": _rmse(al.x, al.y, al.u, al.v, field, sel),
                       "smooth_px": al.meta["regularisation"].get("smooth_px"),
                       "second_order": al.meta["regularisation"].get("second_order_warp")}
                if args.pyaldic:
                    row["pyaldic"] = _pyaldic(args.pyaldic, ref, dfm, roi, subset, field)
                rows.append(row)
            res = {k: np.mean([r[k] for r in rows], axis=0).tolist()
                   for k in ("local", "aldic")}
            py = [r["pyaldic"] for r in rows if r.get("pyaldic")]
            if py:
                res["pyaldic"] = np.mean(py, axis=0).tolist()
            res["ratio"] = [a / b for a, b in zip(res["aldic"], res["local"])]
            res["smooth_px"] = [r["smooth_px"] for r in rows]
            out[f"{name}/{noise:g}"] = res
            line = (f"{name:13s} {noise:4.0f} GL  u/v RMSE  Local {res['local'][0]:.4f}/"
                    f"{res['local'][1]:.4f}  AL-DIC {res['aldic'][0]:.4f}/{res['aldic'][1]:.4f}"
                    f"  ratio {res['ratio'][0]:.3f}/{res['ratio'][1]:.3f}")
            if "pyaldic" in res:
                line += f"  pyALDIC {res['pyaldic'][0]:.4f}/{res['pyaldic'][1]:.4f}"
            print(line, flush=True)
    return out


def lattice_mesh(n: int, step: float = 16.0):
    """A uniform n x n node Q4 mesh (no image needed)."""
    from napari_aldic.engine.dic.global_solve import Q4Mesh

    iy, ix = np.mgrid[0:n, 0:n]
    idx = (iy * n + ix)
    e = np.column_stack([idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(),
                         idx[1:, 1:].ravel(), idx[1:, :-1].ravel()])
    return Q4Mesh(ix.ravel() * step, iy.ravel() * step, e.astype(np.int64))


def solver(args) -> dict:
    from napari_aldic.engine.dic.global_solve import GlobalSolver

    out = {}
    # the default AL-DIC parameters (mu = beta = 0.1) at subset 31, step 8,
    # with the largest automatic smoothing length (half a subset): the
    # stiffest (worst-conditioned) system the automatic choice can build
    step, subset, mu, beta = 8.0, 31, 0.1, 0.1
    for n in args.sizes:
        mesh = lattice_mesh(n, step)
        N = mesh.n_nodes
        rng = np.random.default_rng(n)
        # a smooth field plus local-DIC-like noise, ADMM-like right-hand sides
        u = 0.5 * np.sin(mesh.x / 400.0) + 0.01 * rng.standard_normal(N)
        v = 0.3 * np.cos(mesh.y / 300.0) + 0.01 * rng.standard_normal(N)
        trusted = rng.random(N) > 0.02
        row = {}
        for method in args.methods:
            if method == "direct" and N > args.direct_max:
                continue
            t = time.perf_counter()
            gs = GlobalSolver(mesh, beta=beta * step**2, mu=1.0, weights=trusted,
                              curvature=(0.5 * subset) ** 4 / mu, method=method)
            setup = time.perf_counter() - t
            F = gs.gradients(u, v)
            z = np.zeros(N)
            W = np.zeros((N, 4))
            times = []
            for k in range(3):  # three ADMM-like solves with the same matrix
                t = time.perf_counter()
                uh, vh = gs.solve(F, W, u + 1e-3 * k, v, z, z)
                times.append(time.perf_counter() - t)
            sysr = gs.system
            info = {"setup_s": setup, "first_solve_s": times[0],
                    "later_solve_s": float(np.mean(times[1:])), "uh": uh}
            if method == "direct":
                info["factor_mb"] = (sysr.factor_nnz) * 12 / 2**20
            else:
                info["cg_iterations"] = sysr.iterations
            row[method] = info
        ref = row.get("direct", row.get("amg"))["uh"]
        for info in row.values():
            info["max_diff_px"] = float(np.abs(info.pop("uh") - ref).max())
        out[str(N)] = row
        print(f"{N:8d} unknowns: " + "  ".join(
            f"{m} setup {i['setup_s']:.2f}s solve {i['first_solve_s']:.2f}/"
            f"{i['later_solve_s']:.2f}s"
            + (f" factor {i['factor_mb']:.0f} MB" if "factor_mb" in i else
               f" it {i['cg_iterations'][:2]}") + f" diff {i['max_diff_px']:.1e}"
            for m, i in row.items()), flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="what", required=True)
    a = sub.add_parser("accuracy")
    a.add_argument("--seeds", type=int, default=3)
    a.add_argument("--noise", type=float, nargs="+", default=[2.0, 5.0, 10.0])
    a.add_argument("--cases", nargs="+", default=list(CASES))
    a.add_argument("--pyaldic", metavar="PYTHON")
    a.add_argument("--json")
    s = sub.add_parser("solver")
    s.add_argument("--sizes", type=int, nargs="+", default=[100, 200, 300, 400])
    s.add_argument("--methods", nargs="+", default=["direct", "jacobi", "amg"])
    s.add_argument("--direct-max", type=int, default=400_000)
    s.add_argument("--json")
    args = ap.parse_args(argv)
    out = accuracy(args) if args.what == "accuracy" else solver(args)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
