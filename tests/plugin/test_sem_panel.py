"""The dock's "SEM corrections (HRDIC)" section (issue 27b): a distortion
calibration chosen in the panel is used by the Run (``correlate_sem``), a bad
file is refused with one line naming it, and the choice (paths and hashes)
is kept in a project file and restored."""

from __future__ import annotations

import json

import numpy as np
import pytest

from napari_aldic.engine.sem import DistortionModel
from napari_aldic.engine.synthetic import SEMScan, Translation, make_pattern, sem_image

N = 128
#: a strong field distortion (several px at the corners of this small field)
SCAN = SEMScan((N, N), k1=4e-3, k2=1e-3, p1=8e-3)
SHIFT = (3.0, -2.0)


@pytest.fixture(scope="module")
def sem_pair():
    pat = make_pattern((N, N), margin=30, seed=5)
    ref = sem_image(pat, SCAN, None, noise=1.0, seed=1)
    dfm = sem_image(pat, SCAN, Translation(*SHIFT), noise=1.0, seed=2)
    return np.stack([ref, dfm])


def _calibration(path):
    """The synthetic scan's distortion as an engine calibration file (fitted to
    the exact truth on a grid: no calibration images needed for this test)."""
    model = DistortionModel(4, (N, N), np.zeros(0), np.zeros(0))
    xs = np.linspace(0, N - 1, 17)
    X, Y = np.meshgrid(xs, xs)
    B = model.basis(X, Y)
    dx, dy = SCAN.distortion(X, Y)
    model.coef_x = np.linalg.lstsq(B, dx.ravel(), rcond=None)[0]
    model.coef_y = np.linalg.lstsq(B, dy.ravel(), rcond=None)[0]
    assert np.hypot(dx, dy).max() > 1.0  # a distortion worth correcting
    return model.save(path)


def _docked(viewer):
    from napari_aldic._qt import DICWidget

    widget = DICWidget(viewer)
    viewer.window.add_dock_widget(widget, name="DIC (AL-DIC)", area="right")
    return widget


def _dock(viewer, stack):
    viewer.add_image(stack, name="sem pair")
    w = _docked(viewer)
    w.method.value, w.subset.value, w.step.value = "local", 21, 8
    return w


def test_distortion_file_changes_the_run(make_napari_viewer_proxy, sem_pair, tmp_path):
    path = _calibration(tmp_path / "distortion.json")
    w = _dock(make_napari_viewer_proxy(), sem_pair)
    plain = w._job().run().results[1]
    assert "sem" not in plain.meta
    w.sem.distortion.value = str(path)
    assert w.model.sem.distortion == str(path) and len(w.model.sem.distortion_sha256) == 64
    assert "distortion.json" in w.sem.state.value
    job = w._job()
    assert job.sem is not None and "distortion" in job.sem
    res = job.run().results[1]  # the Run button's job (its worker adds only layers)
    assert res.meta["sem"]["distortion"]["degree"] == 4
    # the corrected field is the specimen's: the rigid shift everywhere (truth), the
    # uncorrected one carries the distortion's gradient
    ok = res.valid & plain.valid
    err_plain = np.hypot(plain.u[ok] - SHIFT[0], plain.v[ok] - SHIFT[1])
    err = np.hypot(res.u[ok] - SHIFT[0], res.v[ok] - SHIFT[1])
    assert ok.sum() > 50 and np.abs(res.u - plain.u)[ok].max() > 0.05
    assert np.sqrt(np.mean(err**2)) < 0.5 * np.sqrt(np.mean(err_plain**2))



def test_the_choice_survives_a_project(make_napari_viewer_proxy, sem_pair, tmp_path):
    """Saved with the project (paths + hashes), restored into the model and the panel."""
    from napari_aldic._qt.sem import SEMChoice

    path = _calibration(tmp_path / "distortion.json")
    tif = tmp_path / "pair.tif"
    import tifffile

    tifffile.imwrite(tif, sem_pair, photometric="minisblack")
    viewer2 = make_napari_viewer_proxy()
    viewer2.open(str(tif), plugin="napari-aldic")
    w2 = _docked(viewer2)
    w2.sem.distortion.value = str(path)
    w2.sem.scan_lines.value = True
    project = w2.save_project(tmp_path / "analysis")
    doc = json.loads(project.read_text(encoding="utf-8"))
    assert doc["sem"]["distortion"] == str(path) and doc["sem"]["scan_lines"] is True
    assert doc["sem"]["distortion_sha256"] == w2.model.sem.distortion_sha256
    w2._remember()  # what a Run remembers for the next dock
    w3 = _docked(make_napari_viewer_proxy())
    assert w3.model.sem is None  # the remembered settings keep no SEM files
    assert w3.open_project(project) is True
    assert w3.model.sem == SEMChoice.from_dict(doc["sem"])
    assert str(w3.sem.distortion.value) == str(path) and w3.sem.scan_lines.value is True
    assert "distortion.json" in w3.sem.state.value


def test_bad_files_are_refused_naming_them(make_napari_viewer_proxy, sem_pair, tmp_path):
    w = _dock(make_napari_viewer_proxy(), sem_pair)
    bad = tmp_path / "not_a_calibration.json"
    bad.write_text(json.dumps({"format": "something else"}), encoding="utf-8")
    w.sem.distortion.value = str(bad)
    assert w.model.sem is None and "not_a_calibration.json" in w.sem.state.value
    assert "\n" not in w.sem.state.value
    w.sem.drift.value = str(tmp_path / "missing.json")
    assert w.model.sem is None and "missing.json" in w.sem.state.value
    assert w._job().sem is None  # the run is a plain one
    # a calibration replaced after it was chosen is refused by the Run, naming it
    good = _calibration(tmp_path / "d.json")
    w.sem.distortion.value = str(good)
    assert w.model.sem.distortion == str(good)
    good.write_text(good.read_text(encoding="utf-8") + " ", encoding="utf-8")
    with pytest.raises(ValueError, match="d.json changed"):
        w._job()
    # stacks: one deformed frame only
    w2 = _dock(make_napari_viewer_proxy(), np.stack([*sem_pair, sem_pair[1]]))
    _calibration(good)
    w2.sem.distortion.value = str(good)
    with pytest.raises(ValueError, match="apply to a pair"):
        w2._job()  # refused before a run starts (the dock shows the message)
    w2.stop.value = 1  # a frame range with one deformed frame is a pair
    assert "SEM corrections: distortion d.json" in w2._job().summary
