"""One rule for untrusted nodes in every export: measured fields are NaN where the
node is not trusted, for accumulative results (which keep the solver's best
attempt in ``u``/``v``) and incremental ones (which store NaN) alike; the best
attempt is exported apart, in ``u_attempt``/``v_attempt``."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io as sio

from napari_aldic.engine import DICResult, Units, track
from napari_aldic.engine.io import (
    export_csv,
    export_davis,
    export_mat,
    export_vtu,
    read_csv,
    read_vtu,
)

UM = Units(pixel_size=0.5, unit="um", frame_interval=0.2, time_unit="s")


def _flag(res: DICResult, nodes) -> DICResult:
    """A copy of ``res`` with ``nodes`` flagged as outliers; u, v keep the attempt."""
    out = DICResult(**{**res.__dict__})
    out.valid = res.valid.copy()
    out.reason = res.reason.copy()
    out.valid[nodes] = False
    out.reason[nodes] = 8
    return out


@pytest.fixture(scope="module")
def incremental():
    """An incremental sequence whose material moves 7 px per frame to the right:
    subsets near the right edge leave the image and are flagged, u = NaN."""
    from napari_aldic.engine import synthetic as S

    shape = (128, 128)
    pat = S.make_pattern(shape, seed=23, margin=40)
    stack = np.stack([S.render(pat, shape, None if k == 0 else S.Translation(7.0 * k, 0.3 * k),
                               n_quad=2, seed=60 + k) for k in range(4)])
    seq = track(stack, subset=21, step=12, reference="incremental")
    assert any((~seq[k].valid).any() for k in range(1, len(seq)))
    assert all(seq[k].valid.sum() > seq[k].valid.size // 2 for k in range(1, len(seq)))
    return seq


def _cases(export_sequence, incremental):
    flagged = [export_sequence[0]] + [_flag(export_sequence[k], [3, 10, 40 + k])
                                      for k in (1, 2, 3)]
    return {"accumulative": flagged, "incremental": incremental}


def _check_columns(get, frames, n_frames):
    """``get(k, name)`` -> exported values of frame k; the rule holds for each frame."""
    for k in range(n_frames):
        res = frames[k]
        bad = ~res.valid
        for name in ("u", "v", "magnitude", "exx", "vx"):
            vals = get(k, name)
            assert np.isnan(vals[bad]).all(), (k, name)
        np.testing.assert_allclose(get(k, "u")[res.valid], 0.5 * res.u[res.valid], rtol=1e-9)
        np.testing.assert_allclose(get(k, "u_attempt"), 0.5 * res.u, rtol=1e-9,
                                   equal_nan=True)  # the attempt; NaN where there is none
        assert np.isfinite(get(k, "u")[res.valid]).all()


@pytest.mark.parametrize("mode", ["accumulative", "incremental"])
def test_csv_and_vtu_follow_the_rule(tmp_path, mode, export_sequence, incremental):
    frames = _cases(export_sequence, incremental)[mode]
    csv = read_csv(export_csv(frames, tmp_path / "r.csv", units=UM))
    assert "untrusted nodes" in csv["header"]
    cols = csv["columns"]

    def from_csv(k, name):
        return cols[name][cols["frame"] == k]

    _check_columns(from_csv, frames, 4)
    paths = export_vtu(frames, tmp_path / "r.vtu", units=UM)

    def from_vtu(k, name):
        return read_vtu(paths[k])["point_data"][name]

    _check_columns(from_vtu, frames, 4)
    for k in range(4):
        disp = read_vtu(paths[k])["point_data"]["displacement"]
        assert (np.isnan(disp[:, 0]) == ~frames[k].valid).all()  # the vector too


@pytest.mark.parametrize("mode", ["accumulative", "incremental"])
def test_mat_and_davis_follow_the_rule(tmp_path, mode, export_sequence, incremental):
    frames = _cases(export_sequence, incremental)[mode]
    d = sio.loadmat(export_mat(frames, tmp_path / "r.mat", units=UM))
    assert "NaN" in str(d["untrusted_rule"][0])

    def from_mat(k, name):
        return d["frames"][0, k][name].ravel()

    _check_columns(from_mat, frames, 4)
    # the stored result stays exact in u_px (load_mat rebuilds it bit for bit)
    np.testing.assert_array_equal(from_mat(3, "u_px"), frames[3].u)
    path = export_davis(frames[3], tmp_path / "d.txt")[0]
    table = np.loadtxt(path, skiprows=1)
    res = frames[3]
    at = {(x, y): u for x, y, u in table[:, :3]}
    for i in np.nonzero(~res.valid)[0]:
        assert np.isnan(at[(res.x[i], res.y[i])])
