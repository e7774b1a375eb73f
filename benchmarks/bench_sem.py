"""HRDIC in the SEM (issue 27) at the issue's size: 1024² synthetic SEM images,
subset 31, step 8. Figures before/after each correction against exact truth.

    PYTHONPATH=src python benchmarks/bench_sem.py [--size 1024] [--out sem.json]

Cases (engine/synthetic/sem.py):
* distortion: Brown-Conrady k1 = 0.15e-3, k2 = 0.05e-3, p1 = 0.7e-3 (1.3-1.9 px at
  the corners), 8 calibration images translated by up to 90 px (~9 % of the field),
  test pair exx 0.5 %, eyy -0.15 %, stage move (35, -28) px;
* scan lines: 2 % of each image's rows shifted +-0.3-1.0 px in blocks of 2-5 rows,
  same test deformation;
* drift: 6 images back to back (dwell 1 us, line 1.124 ms, frame 1.15 s), drift
  0.3 px/s + 0.15 px/s² along x, -0.2 px/s + 0.1 px/s² along y; image 3 is
  loaded (the test deformation), images 0-2, 4, 5 calibrate;
* combined (``--cases combined``): all three at once, scan lines in every image.
Every case adds noise of 2 grey levels (8 bits). Errors over nodes 40 px inside
the image; strain by compute_strain (plane fit, window 5).
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np

from napari_aldic import __version__
from napari_aldic.engine import compute_strain, correlate, correlate_sem
from napari_aldic.engine.sem import ScanLines, ScanTiming, calibrate_distortion, calibrate_drift
from napari_aldic.engine.synthetic import (
    Affine,
    SEMScan,
    Translation,
    make_pattern,
    random_line_shifts,
    sem_image,
)

EXX, EYY, STAGE = 0.005, -0.0015, (35.0, -28.0)


def errors(res, field, n, margin=40) -> dict:
    ux, uy = field.displacement(res.x, res.y)
    inner = (res.x > margin) & (res.x < n - margin) & (res.y > margin) & (res.y < n - margin)
    ok = res.valid & inner
    st = compute_strain(res)
    e = {"exx": st.exx[ok] - EXX, "eyy": st.eyy[ok] - EYY, "exy": st.exy[ok]}
    rows = np.unique(res.y[ok])
    worst = max(abs(np.nanmean(st.exy[ok & (res.y == y)])) for y in rows)
    return {"rmse_px": float(np.sqrt(np.mean((res.u - ux)[ok] ** 2 + (res.v - uy)[ok] ** 2))),
            **{f"mean_{k}": float(np.nanmean(v)) for k, v in e.items()},
            **{f"std_{k}": float(np.nanstd(v)) for k, v in e.items()},
            "worst_row_exy": float(worst), "trusted_interior": float(ok.sum() / inner.sum())}


def distortion_case(n: int, field) -> dict:
    scan = SEMScan((n, n), k1=0.15e-3, k2=0.05e-3, p1=0.7e-3)
    pat = make_pattern((n, n), margin=140, seed=3)
    a = 90.0 * n / 1024
    moves = [(0, 0), (a, 0), (-a, 0), (0, a), (0, -a), (0.7 * a, 0.7 * a),
             (-0.7 * a, 0.7 * a), (0.7 * a, -0.7 * a)]
    cal = [sem_image(pat, scan, Translation(*m), noise=2, seed=10 + k)
           for k, m in enumerate(moves)]
    t0 = time.perf_counter()
    model = calibrate_distortion(cal, degree=4)
    t_cal = time.perf_counter() - t0
    ref = sem_image(pat, scan, None, noise=2, seed=100)
    dfm = sem_image(pat, scan, field, noise=2, seed=101)
    xs = np.linspace(0, n - 1, 17)
    X, Y = np.meshgrid(xs, xs)
    d_err = np.hypot(*(np.array(model.displacement(X, Y)) - np.array(scan.distortion(X, Y))))
    return {"corner_px": float(np.hypot(*scan.distortion(X, Y)).max()),
            "calibration_s": t_cal, "fit_rms_px": model.residual_rms,
            "model_error_max_px": float(d_err.max()),
            "uncorrected": errors(correlate(ref, dfm), field, n),
            "corrected": errors(correlate_sem(ref, dfm, distortion=model), field, n)}


def scan_line_case(n: int, field) -> dict:
    scan = SEMScan((n, n))
    pat = make_pattern((n, n), margin=80, seed=5)
    l_ref, l_def = random_line_shifts(n, seed=1), random_line_shifts(n, seed=2)
    ref = sem_image(pat, scan, None, line_shifts=l_ref, noise=2, seed=1)
    dfm = sem_image(pat, scan, field, line_shifts=l_def, noise=2, seed=2)
    t0 = time.perf_counter()
    res = correlate_sem(ref, dfm, scan_lines=True)
    t_run = time.perf_counter() - t0
    lines = ScanLines.from_meta(res.meta["sem"]["scan_lines"])
    return {"shifted_rows": [int(np.count_nonzero(l_ref)), int(np.count_nonzero(l_def))],
            "found_rows": [int(np.count_nonzero(lines.reference)),
                           int(np.count_nonzero(lines.deformed))],
            "shift_error_max_px": float(max(np.abs(lines.reference - l_ref).max(),
                                            np.abs(lines.deformed - l_def).max())),
            "corrected_run_s": t_run,
            "uncorrected": errors(correlate(ref, dfm), field, n),
            "corrected": errors(res, field, n)}


def drift_case(n: int, field) -> dict:
    scan = SEMScan((n, n), dwell=1e-6, flyback=1e-4, drift_x=(0.3, 0.15),
                   drift_y=(-0.2, 0.1))
    F = scan.frame_time
    pat = make_pattern((n, n), margin=80, seed=7)
    times = [k * F for k in range(6)]
    imgs = [sem_image(pat, scan, field if k == 3 else None, start_time=times[k], noise=2,
                      seed=20 + k) for k in range(6)]
    calib = (0, 1, 2, 4, 5)
    model = calibrate_drift([imgs[k] for k in calib], ScanTiming(scan.dwell, scan.line_time),
                            start_times=[times[k] for k in calib], degree=3)
    t = np.linspace(0, 6 * F, 61)
    err = np.hypot(*(np.array(model.displacement(t)) - np.array(scan.drift(t))))
    return {"frame_time_s": F, "drift_at_loaded_px": [float(v) for v in scan.drift(4 * F)],
            "model_error_max_px": float(err.max()), "fit_rms_px": model.residual_rms,
            "uncorrected": errors(correlate(imgs[0], imgs[3]), field, n),
            "corrected": errors(correlate_sem(imgs[0], imgs[3], drift=model,
                                              start_times=(times[0], times[3])), field, n)}


def combined_case(n: int, field) -> dict:
    """All three at once: distortion (calibrated from short, drift-free scans),
    drift (calibrated from a series corrected for the distortion) and scan
    lines in every image of the series."""
    scan = SEMScan((n, n), k1=0.15e-3, k2=0.05e-3, p1=0.7e-3, dwell=1e-6, flyback=1e-4,
                   drift_x=(0.3, 0.15), drift_y=(-0.2, 0.1))
    pat = make_pattern((n, n), margin=140, seed=9)
    a = 90.0 * n / 1024
    moves = [(0, 0), (a, 0), (-a, 0), (0, a), (0, -a), (0.7 * a, 0.7 * a),
             (-0.7 * a, 0.7 * a), (0.7 * a, -0.7 * a)]
    cal = [sem_image(pat, scan, Translation(*m), noise=2, seed=40 + k, use_drift=False)
           for k, m in enumerate(moves)]
    dist = calibrate_distortion(cal, degree=4)
    F = scan.frame_time
    times = [k * F for k in range(6)]
    imgs = [sem_image(pat, scan, field if k == 3 else None, start_time=times[k], noise=2,
                      seed=60 + k, line_shifts=random_line_shifts(n, seed=70 + k))
            for k in range(6)]
    calib = (0, 1, 2, 4, 5)
    drift = calibrate_drift([imgs[k] for k in calib], ScanTiming(scan.dwell, scan.line_time),
                            start_times=[times[k] for k in calib], degree=3, distortion=dist)
    res = correlate_sem(imgs[0], imgs[3], distortion=dist, drift=drift, scan_lines=True,
                        start_times=(times[0], times[3]))
    return {"uncorrected": errors(correlate(imgs[0], imgs[3]), field, n),
            "corrected": errors(res, field, n)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--out", default="sem_results.json")
    ap.add_argument("--cases", nargs="+", default=["distortion", "scan_lines", "drift"])
    a = ap.parse_args()
    n = a.size
    field = Affine.strain_rotation(exx=EXX, eyy=EYY, center=((n - 1) / 2,) * 2,
                                   t=tuple(s * n / 1024 for s in STAGE))
    out = {"napari-aldic": __version__, "machine": platform.platform(), "size": n}
    cases = {"distortion": distortion_case, "scan_lines": scan_line_case, "drift": drift_case,
             "combined": combined_case}
    for name in a.cases:
        t0 = time.perf_counter()
        out[name] = cases[name](n, field)
        out[name]["case_s"] = time.perf_counter() - t0
        print(name, json.dumps(out[name], indent=1), flush=True)
    with open(a.out, "w") as fh:
        json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
