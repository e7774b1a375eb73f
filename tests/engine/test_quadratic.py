"""Second-order (quadratic) subset shape function of Local IC-GN, against exact truth."""

from __future__ import annotations

import numpy as np
import pytest

from napari_aldic.engine import DICParams, Settings, correlate, synthetic as S
from napari_aldic.engine.dic.icgn import icgn_solve
from napari_aldic.engine.dic.images import prepare_images


class Bend(S.DisplacementField):
    """An exact quadratic displacement field about (64, 64)."""

    def displacement(self, X, Y):
        x = np.asarray(X, float) - 64.0
        y = np.asarray(Y, float) - 64.0
        return (0.3 + 8e-4 * x * x + 4e-4 * x * y,
                -0.2 + 6e-4 * y * y - 4e-4 * x * x)


def _nodes(shape, half, step=6):
    h, w = shape
    xs, ys = np.meshgrid(np.arange(half + 2, w - half - 2, step),
                         np.arange(half + 2, h - half - 2, step))
    return xs.ravel().astype(np.int64), ys.ravel().astype(np.int64)


def test_quadratic_recovers_exact_quadratic_field_that_affine_cannot():
    field = Bend()
    ref, dfm = S.speckle_pair((128, 128), field, seed=3)
    im = prepare_images(ref.astype(float), dfm.astype(float), "cubic")
    nx, ny = _nodes(ref.shape, 10)
    ut, vt = field.displacement(nx, ny)
    p0 = np.zeros((nx.size, 6))
    p0[:, 0], p0[:, 3] = np.round(ut), np.round(vt)  # integer start, as an FFT guess
    args = (im.f, im.fgx, im.fgy, im.g_spline, nx, ny, p0, np.ones(nx.size, bool),
            -np.ones(nx.size, np.int32), np.ones((0, 21, 21), np.uint8), 10)
    sol = {shape: icgn_solve(*args, shape=shape) for shape in ("affine", "quadratic")}
    ok = (sol["affine"][3] == 0) & (sol["quadratic"][3] == 0)
    assert ok.mean() > 0.9  # a few corner subsets move out of the image
    err = {}
    for shape, (p, _, _, _) in sol.items():
        err[shape] = float(np.sqrt(np.mean(((p[:, 0] - ut) ** 2 + (p[:, 3] - vt) ** 2)[ok])))
    # the gradient at the node is exact for a quadratic field too
    gx = 16e-4 * (nx - 64.0) + 4e-4 * (ny - 64.0)
    assert np.max(np.abs(sol["quadratic"][0][ok, 1] - gx[ok])) < 4e-3
    # affine subsets average the curvature: u + (uxx + uyy) h^2/6-ish bias
    assert err["affine"] > 0.02
    assert err["quadratic"] < 0.2 * err["affine"]
    assert err["quadratic"] < 0.005  # the cubic-spline bias of this speckle, no more


def test_quadratic_keeps_amplitude_of_short_sine():
    wave = S.Sinusoid(0.0, 0.5, wavelength=36.0)
    ref, dfm = S.speckle_pair((96, 160), wave, seed=5)
    amp = {}
    for shape in ("affine", "quadratic"):
        res = correlate(ref, dfm, subset=21, step=4, shape_function=shape)
        _, vt = wave.displacement(res.x.astype(float), res.y.astype(float))
        ok = res.valid
        assert ok.mean() > 0.9
        amp[shape] = float(np.sum(res.v[ok] * vt[ok]) / np.sum(vt[ok] ** 2))
    # affine: a wave of period 36 px loses (k h)^2/6 ~ 0.2 of its amplitude at h = 10
    assert amp["affine"] < 0.9
    assert amp["quadratic"] > 0.95
    assert abs(1 - amp["quadratic"]) < 0.3 * abs(1 - amp["affine"])


def test_aldic_accepts_quadratic_initial_local_step():
    field = Bend()
    ref, dfm = S.speckle_pair((128, 128), field, seed=4)
    res = correlate(ref, dfm, subset=21, step=8, method="aldic", shape_function="quadratic")
    ut, vt = field.displacement(res.x.astype(float), res.y.astype(float))
    assert res.valid.mean() > 0.9
    e = np.sqrt(np.mean(((res.u - ut) ** 2 + (res.v - vt) ** 2)[res.valid]))
    assert e < 0.01


def test_shape_function_param_validated_and_round_trips(tmp_path):
    with pytest.raises(ValueError, match="shape_function='cubic' must be 'affine' or "
                                         "'quadratic'"):
        DICParams(shape_function="cubic")
    with pytest.raises(ValueError, match="shape_function"):
        DICParams(shape_function=2)
    p = DICParams(shape_function="quadratic")
    assert DICParams.from_dict(p.to_dict()).shape_function == "quadratic"
    assert DICParams().shape_function == "affine"
    from napari_aldic.engine.io import read_settings, write_settings

    path = write_settings(tmp_path / "s.json", Settings(params=p))
    assert read_settings(path).params.shape_function == "quadratic"


def test_cli_shape_option(tmp_path):
    from napari_aldic.cli.app import main

    out = tmp_path / "p.json"
    assert main(["params", str(out), "--shape", "quadratic"]) == 0
    from napari_aldic.engine.io import read_settings

    assert read_settings(out).params.shape_function == "quadratic"
    assert main(["params", str(out), "--shape", "cubic"]) != 0
