"""HRDIC in the SEM (issue 27): distortion, scan lines and drift against the
exact truth of the synthetic SEM model (small images to stay fast)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_aldic.engine import compute_strain, correct_distortion, correlate, correlate_sem
from napari_aldic.engine.sem import (
    DistortionError,
    ScanLines,
    ScanTiming,
    calibrate_distortion,
    calibrate_drift,
    fit_distortion,
    load_distortion,
    load_drift,
    remove_scan_lines,
)
from napari_aldic.engine.synthetic import (
    Affine,
    SEMScan,
    Translation,
    make_pattern,
    random_line_shifts,
    sem_image,
)

N = 256
C = ((N - 1) / 2,) * 2
STRAIN = Affine.strain_rotation(exx=0.005, eyy=-0.0015, center=C, t=(9.0, -7.0))
#: distortion of about 1.2-1.9 px at the corners of a 1024² field, scaled to N
SCAN = SEMScan((N, N), k1=0.6e-3, k2=0.2e-3, p1=2.8e-3)


def _errors(res, field, margin=24):
    """RMSE (px), mean and std of the exx error over interior trusted nodes."""
    ux, uy = field.displacement(res.x, res.y)
    inner = (res.x > margin) & (res.x < N - margin) & (res.y > margin) & (res.y < N - margin)
    ok = res.valid & inner
    st = compute_strain(res)
    exx = st.exx[ok] - 0.005
    return (float(np.sqrt(np.mean((res.u - ux)[ok] ** 2 + (res.v - uy)[ok] ** 2))),
            float(np.nanmean(exx)), float(ok.sum() / inner.sum()))


@pytest.fixture(scope="module")
def distortion_case():
    pat = make_pattern((N, N), margin=60, seed=3)
    a = 24.0
    moves = [(0, 0), (a, 0), (-a, 0), (0, a), (0, -a), (a, a), (-a, a), (a, -a)]
    cal = [sem_image(pat, SCAN, Translation(*m), noise=1.5, seed=10 + k)
           for k, m in enumerate(moves)]
    ref = sem_image(pat, SCAN, None, noise=1.5, seed=100)
    dfm = sem_image(pat, SCAN, STRAIN, noise=1.5, seed=101)
    return cal, ref, dfm, moves


@pytest.mark.slow
def test_distortion_calibration_recovers_truth(distortion_case, tmp_path):
    cal, ref, dfm, moves = distortion_case
    model = calibrate_distortion(cal, degree=5)
    xs = np.linspace(0, N - 1, 9)
    X, Y = np.meshgrid(xs, xs)
    tx, ty = SCAN.distortion(X, Y)
    fx, fy = model.displacement(X, Y)
    assert np.hypot(tx, ty).max() > 1.0  # a real distortion to find
    assert np.abs(fx - tx).max() < 0.05 and np.abs(fy - ty).max() < 0.05
    trans = np.array([im["translation_px"] for im in model.images])
    assert np.abs(trans - np.array(moves)).max() < 0.05
    back = load_distortion(model.save(tmp_path / "d.json"))
    assert np.allclose(back.displacement(X, Y), model.displacement(X, Y))
    assert len(back.images) == 8 and all(len(im["sha256"]) == 64 for im in back.images)
    # the correction meets the targets on this pair
    res = correlate(ref, dfm)
    rmse0, mean0, _ = _errors(res, STRAIN)
    rmse1, mean1, trusted = _errors(correct_distortion(res, model), STRAIN)
    assert abs(mean0) > 3e-4 and abs(mean1) < 1e-4
    assert rmse1 < 0.5 * rmse0 and trusted >= 0.95
    fixed = correlate_sem(ref, dfm, distortion=model)
    assert fixed.meta["sem"]["distortion"]["degree"] == 5
    assert np.allclose(fixed.u, correct_distortion(res, model).u, atol=1e-9)


def test_distortion_errors(distortion_case):
    cal, ref, _, _ = distortion_case
    with pytest.raises(DistortionError, match="at least 3"):
        calibrate_distortion(cal[:2])
    with pytest.raises(DistortionError, match="degree 1"):
        fit_distortion([], (N, N), degree=1)
    # translations along x only cannot reveal terms that vary along y alone
    xs = np.linspace(10, N - 10, 20)
    X, Y = [a.ravel() for a in np.meshgrid(xs, xs)]
    pair = (X, Y, np.full_like(X, 5.0), np.zeros_like(X))
    with pytest.raises(DistortionError, match="both x and y"):
        fit_distortion([pair, pair], (N, N), degree=3)
    model = calibrate_distortion(cal[:4], degree=2)
    res = correlate(ref[:128, :128], ref[:128, :128])
    with pytest.raises(DistortionError, match="256 x 256 px images"):
        correct_distortion(res, model)


def test_scan_lines_removed():
    pat = make_pattern((N, N), margin=40, seed=5)
    field = Affine.strain_rotation(exx=0.005, eyy=-0.0015, center=C, t=(2.3, -1.6))
    l_ref, l_def = random_line_shifts(N, seed=1), random_line_shifts(N, seed=2)
    ref = sem_image(pat, SEMScan((N, N)), None, line_shifts=l_ref, noise=1.5, seed=1)
    dfm = sem_image(pat, SEMScan((N, N)), field, line_shifts=l_def, noise=1.5, seed=2)
    rmse0, _, _ = _errors(correlate(ref, dfm), field)
    res = correlate_sem(ref, dfm, scan_lines=True)
    rmse1, _, trusted = _errors(res, field)
    assert rmse1 < 0.5 * rmse0 and rmse1 < 0.02 and trusted >= 0.95
    lines = ScanLines.from_meta(res.meta["sem"]["scan_lines"])
    # each image's own shifts found, not the other's
    assert np.abs(lines.reference - l_ref).max() < 0.1
    assert np.abs(lines.deformed - l_def).max() < 0.1
    st = compute_strain(res)
    ok = res.valid
    rows = np.unique(res.y[ok])
    worst = max(abs(np.nanmean(st.exy[ok & (res.y == y)])) for y in rows)
    assert worst < 5e-4


def test_remove_scan_lines_inverts_shift():
    pat = make_pattern((64, 64), seed=2)
    shifts = np.zeros(64)
    shifts[20:23] = 0.7
    clean = sem_image(pat, SEMScan((64, 64)), bit_depth=None)
    shifted = sem_image(pat, SEMScan((64, 64)), line_shifts=shifts, bit_depth=None)
    back = remove_scan_lines(shifted, shifts)
    assert np.abs(back - clean)[:, 4:-4].max() < 3.0
    assert np.abs(shifted - clean)[20:23, 4:-4].max() > 30.0
    with pytest.raises(ValueError, match="3 scan-line shifts"):
        remove_scan_lines(clean, np.zeros(3))


def test_drift_calibrated_and_removed(tmp_path):
    scan = SEMScan((N, N), dwell=2e-6, flyback=1e-4, drift_x=(0.6, 0.1), drift_y=(-0.4, 0.08))
    F = scan.frame_time
    pat = make_pattern((N, N), margin=40, seed=7)
    field = Affine.strain_rotation(exx=0.005, eyy=-0.0015, center=C, t=(2.3, -1.6))
    times = [k * F for k in range(6)]  # back to back; frame 3 is loaded
    imgs = [sem_image(pat, scan, field if k == 3 else None, start_time=times[k],
                      noise=1.5, seed=20 + k) for k in range(6)]
    timing = ScanTiming(scan.dwell, scan.line_time)
    model = calibrate_drift([imgs[k] for k in (0, 1, 2, 4, 5)], timing,
                            start_times=[times[k] for k in (0, 1, 2, 4, 5)])
    t = np.linspace(0, 6 * F, 13)
    assert np.abs(np.array(model.displacement(t)) - np.array(scan.drift(t))).max() < 0.02
    model = load_drift(model.save(tmp_path / "drift.json"))
    rmse0, _, _ = _errors(correlate(imgs[0], imgs[3]), field)
    res = correlate_sem(imgs[0], imgs[3], drift=model, start_times=(times[0], times[3]))
    rmse1, _, _ = _errors(res, field)
    assert rmse0 > 0.2 and rmse1 < 0.02
    # frames of the series are recognised by their pixels
    assert model.start_time_of(imgs[1]) == pytest.approx(times[1])
    with pytest.raises(DistortionError, match="deformed image is not in the drift"):
        correlate_sem(imgs[0], imgs[3], drift=model)


def test_scan_lines_with_a_roi_hole():
    n = 160
    pat = make_pattern((n, n), margin=30, seed=8)
    shifts = np.zeros(n)
    shifts[60:63], shifts[110:114] = 0.8, -0.5
    field = Translation(1.3, -0.7)
    ref = sem_image(pat, SEMScan((n, n)), None, noise=1.0, seed=3)
    dfm = sem_image(pat, SEMScan((n, n)), field, line_shifts=shifts, noise=1.0, seed=4)
    yy, xx = np.mgrid[0:n, 0:n]
    roi = np.hypot(xx - 80, yy - 80) > 25  # a hole: no material there in either image
    res = correlate_sem(ref, dfm, roi=roi, scan_lines=True)
    lines = ScanLines.from_meta(res.meta["sem"]["scan_lines"])
    assert np.abs(lines.deformed - shifts).max() < 0.1
    assert np.abs(lines.reference).max() == 0.0
