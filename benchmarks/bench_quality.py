"""Measurement quality: predicted uncertainty against Monte-Carlo, subset advice.

Usage::

    python benchmarks/bench_quality.py            # full tables (30 realisations)
    python benchmarks/bench_quality.py --quick    # 10 realisations, fewer rows

1. **Uncertainty**: one synthetic pair (exact truth: a translation), many
   noise realisations (independent white noise in both images); per node the
   standard deviation of the measured displacement over the realisations is
   the actual uncertainty. The table gives the median over nodes of
   predicted/actual for the model now stored in ``u_std``/``v_std``
   (``dic.quality``; for AL-DIC the smoothed ``u``, ``v`` by linear noise
   propagation through the ADMM run, ``dic.uncertainty_aldic``) and for the
   previous 2 x 2 model of the subset displacements (``dic.reliability``,
   against the scatter of ``u_local`` for AL-DIC); the last column is the
   measured smoothing gain, scatter of ``u`` / scatter of ``u_local``.
2. **Advice**: the subset ``advise_subset`` recommends for a target, and the
   measured displacement noise of a static pair (fresh noise) at that subset.
3. **Cost**: ``advise_subset`` on 1024² (CPU seconds) and the share of a
   one-thread ``correlate`` spent on the quality fields (same run).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from napari_aldic.engine import advise_subset, correlate, synthetic as S
from napari_aldic.engine.dic.quality import speckle_quality
from napari_aldic.engine.dic.regularise import gradient_noise_gain
from napari_aldic.engine.dic.reliability import SubsetStats, displacement_variance


def _old_model(ref, res, sub):
    """The previous prediction: 2 x 2 matrix, residual noise, full E."""
    q = speckle_quality(ref, res.x.astype(int), res.y.astype(int), sub)
    k = q.hessian.shape[1] // 2
    h = q.hessian
    st = SubsetStats(np.column_stack([q.m, q.var_f, h[:, 0, 0], h[:, 0, k], h[:, k, k]]))
    var_e = (1 - np.minimum(res.zncc, 1)) * q.var_f
    return np.sqrt(displacement_variance(st, var_e, gradient_noise_gain(3)))


def uncertainty_row(method, shift, noise, sub, n, size=192, step=10, curved=False):
    fld = S.Translation(*shift)
    if curved:  # a curved field: AL-DIC's second-order warp feeds back curvature
        fld = S.Sum([fld, S.Sinusoid(amplitude_u=1.0, amplitude_v=1.0, wavelength=96.0)])
    ref0, dfm0 = S.speckle_pair((size, size), fld, seed=3, bit_depth=None)
    rng = np.random.default_rng(1)
    d_loc, d_glob, new, old = [], [], [], []
    for _ in range(n):
        ref = ref0 + rng.normal(0, noise, ref0.shape)
        dfm = dfm0 + rng.normal(0, noise, ref0.shape)
        res = correlate(ref, dfm, subset=sub, step=step, method=method, max_uncertainty=None,
                        interpolation="cubic")
        loc = res.u_local is not None
        d_loc.append(np.stack([res.u_local if loc else res.u, res.v_local if loc else res.v]))
        d_glob.append(np.stack([res.u, res.v]))
        new.append(np.stack([res.u_std, res.v_std]))
        old.append(_old_model(ref, res, sub).T)
    d_loc, d_glob, new, old = map(np.array, (d_loc, d_glob, new, old))
    ok = (np.isfinite(d_loc).all(axis=(0, 1)) & np.isfinite(new).all(axis=(0, 1))
          & np.isfinite(old).all(axis=(0, 1)))
    act = d_loc[:, :, ok].std(axis=0, ddof=1)
    act_g = d_glob[:, :, ok].std(axis=0, ddof=1)
    med = lambda p, a: float(np.median(np.median(p[:, :, ok], axis=0) / a))  # noqa: E731
    return {"method": method, "shift": shift, "noise": noise, "subset": sub,
            "actual_px": float(np.median(act_g)), "new": med(new, act_g), "old": med(old, act),
            "u_gain": float(np.median(act_g / act)), "new_u": med(new[:, :1], act_g[:1]),
            "new_v": med(new[:, 1:], act_g[1:]), "nodes": int(ok.sum())}


def advice_row(noise, target, size=512):
    ref, _ = S.speckle_pair((size, size), S.Translation(0, 0), noise=noise, seed=11)
    adv = advise_subset(ref, target_noise=target)
    if adv.recommended is None:
        return {"noise": noise, "target": target, "subset": None}
    r0, d0 = S.speckle_pair((size, size), S.Translation(0, 0), noise=noise, seed=11)
    res = correlate(r0, d0, subset=adv.recommended, step=adv.recommended // 2)
    ok = res.valid
    row = next(r for r in adv.rows if r["subset"] == adv.recommended)
    meas = float(np.sqrt(0.5 * (np.var(res.u[ok]) + np.var(res.v[ok]))))
    return {"noise": noise, "target": target, "subset": adv.recommended,
            "predicted_median_px": row["median_std_px"], "measured_px": meas,
            "noise_est": adv.noise}


def cost():
    ref, dfm = S.speckle_pair((1024, 1024), S.Translation(1.2, 0.3), noise=3.0, seed=2)
    t = time.process_time()
    advise_subset(ref, target_noise=0.01)
    t_adv = time.process_time() - t
    # one Numba thread: the stage timings are then CPU-bound on one core alike
    res = correlate(ref, dfm, subset=31, step=8, n_threads=1)
    tm = res.meta["timing"]
    t_local = (tm["quality"], tm["total"])
    # AL-DIC: the quality fields include the noise propagation through ADMM
    tm = correlate(ref, dfm, subset=31, step=8, method="aldic", n_threads=1).meta["timing"]
    return t_adv, t_local, (tm["quality"], tm["total"])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--cost", action="store_true", help="only the cost line")
    ap.add_argument("--advice", action="store_true", help="only the advice table")
    ap.add_argument("--method", choices=("local", "aldic"), help="uncertainty rows of one "
                    "method only (then no advice table)")
    a = ap.parse_args()
    n = 10 if a.quick else 30
    if a.cost:
        _print_cost(*cost())
        return
    if not a.advice:
        uncertainty_table(n, a.quick, a.method)
        if a.method:
            return
    advice_table()
    _print_cost(*cost())


def _print_cost(t_adv, local, aldic) -> None:
    print(f"\nadvise_subset on 1024²: {t_adv:.2f} CPU s; correlate 1024² (subset 31, step 8, "
          "one thread), quality fields of the total:")
    for name, (t_q, t_tot) in (("local", local), ("aldic", aldic)):
        print(f"  {name}: {t_q:.3f} s of {t_tot:.3f} s ({100 * t_q / t_tot:.0f} %)")


def uncertainty_table(n: int, quick: bool, only: str | None = None) -> None:
    print("| method | shift (px) | noise (GL) | subset | actual std (px) | new/actual "
          "(u; v) | old/actual local | actual / actual local | nodes |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    shifts = [(2.3, -1.4)] if quick else [(2.3, -1.4), (2.5, -1.5), (2.0, -1.0)]
    for method in (only,) if only else ("local", "aldic"):
        for shift in (shifts if method == "local" else shifts[:1]):
            for noise in (2.0, 5.0, 10.0):
                for sub in (21, 31):
                    # AL-DIC at step 8: subsets overlap more (correlated errors)
                    r = uncertainty_row(method, shift, noise, sub, n,
                                        step=8 if method == "aldic" else 10)
                    _print_row(r)
    if only != "local":
        for noise in (2.0, 5.0, 10.0):  # curved field, 21 px
            r = uncertainty_row("aldic", (2.3, -1.4), noise, 21, n, step=8, curved=True)
            _print_row(r | {"shift": "(2.3, -1.4) + sine"})
    print()


def _print_row(r: dict) -> None:
    print(f"| {r['method']} | {r['shift']} | {r['noise']:g} | {r['subset']} | "
          f"{r['actual_px']:.4f} | {r['new']:.3f} ({r['new_u']:.3f}; {r['new_v']:.3f}) | "
          f"{r['old']:.3f} | {r['u_gain']:.3f} | {r['nodes']} |", flush=True)


def advice_table() -> None:
    print("| noise (GL) | target (px) | advised subset | predicted median (px) | "
          "measured std (px) | measured/target |")
    print("| --- | --- | --- | --- | --- | --- |")
    for noise in (2.0, 5.0, 10.0):
        for target in (0.005, 0.01, 0.02):
            r = advice_row(noise, target)
            if r["subset"] is None:
                print(f"| {noise:g} | {target:g} | none | | | |")
                continue
            print(f"| {noise:g} | {target:g} | {r['subset']} | {r['predicted_median_px']:.4f} | "
                  f"{r['measured_px']:.4f} | {r['measured_px'] / target:.2f} |", flush=True)


if __name__ == "__main__":
    main()
