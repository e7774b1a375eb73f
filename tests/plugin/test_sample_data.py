"""npe2 sample data and the napari.yaml manifest."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from napari_aldic import _sample_data as sd
from napari_aldic.engine import correlate

REPO = Path(__file__).resolve().parents[2]  # the repository root


def _check_layers(layers, types):
    assert [t for _, _, t in layers] == types
    for data, kwargs, _ in layers:
        assert isinstance(kwargs["name"], str) and kwargs["name"]
        assert isinstance(data, np.ndarray)


def test_translation_pair_has_the_stated_shift():
    layers = sd.make_translation_pair()
    _check_layers(layers, ["image"])
    stack, kwargs, _ = layers[0]
    assert stack.shape == (2, 256, 256) and stack.dtype == np.uint8
    truth = kwargs["metadata"]["truth"]
    assert (truth["u"], truth["v"]) == sd.TRANSLATION
    assert 0 < abs(truth["u"]) < 1 and 0 < abs(truth["v"]) < 1  # sub-pixel
    res = correlate(stack[0], stack[1], subset=31, step=16)
    assert res.valid.mean() > 0.95
    assert np.abs(res.u[res.valid] - truth["u"]).max() < 0.01
    assert np.abs(res.v[res.valid] - truth["v"]).max() < 0.01


def test_crack_pair_with_roi_labels():
    from napari_aldic.engine.synthetic import ModeICrack

    layers = sd.make_crack_pair()
    _check_layers(layers, ["image", "labels"])
    (stack, kwargs, _), (labels, _, _) = layers
    assert stack.shape == (2, 256, 256) and labels.shape == (256, 256)
    assert np.issubdtype(labels.dtype, np.integer) and set(np.unique(labels)) == {0, 1}
    t = kwargs["metadata"]["truth"]
    tip_x, tip_y = (int(c) for c in t["tip"])
    assert (labels[tip_y, :tip_x] == 0).all()  # the slot along the crack
    assert (labels[tip_y, tip_x + 2:] == 1).all()  # material ahead of the tip
    assert labels.mean() > 0.98

    field = ModeICrack(tip=tuple(t["tip"]), amplitude=t["amplitude"], nu=t["nu"],
                       t=tuple(t["t"]))
    res = correlate(stack[0], stack[1], roi=labels > 0, subset=31, step=8)
    ut, vt = field.displacement(res.x, res.y)
    far = res.valid & (np.hypot(res.x - tip_x, res.y - tip_y) > 40)
    assert far.sum() > 200
    err = np.hypot(res.u - ut, res.v - vt)[far]
    assert np.sqrt(np.mean(err**2)) < 0.02
    # the two faces open in opposite directions behind the tip
    behind = res.valid & (res.x < tip_x - 40) & (np.abs(res.y - tip_y) < 20)
    assert res.v[behind & (res.y < tip_y)].mean() < -0.5
    assert res.v[behind & (res.y > tip_y)].mean() > 0.5


def test_open_hole_pair_and_its_roi():
    layers = sd.load_open_hole_pair()
    _check_layers(layers, ["image", "labels"])
    (stack, kwargs, _), (roi, _, _) = layers
    assert stack.shape == (2, 1040, 400) and stack.dtype == np.uint8
    assert not np.array_equal(stack[0], stack[1])
    assert roi.shape == (1040, 400)
    assert roi[540, 190] == 0  # centre of the hole
    assert roi[540, 10] == 0 and roi[540, 390] == 0  # background strips
    assert roi[200, 200] == 1 and roi[900, 100] == 1  # speckled material
    assert 0.7 < roi.mean() < 0.82
    assert "BSD-3-Clause" in kwargs["metadata"]["source"]


def test_open_hole_files_ship_with_their_licence():
    folder = sd.sample_data_dir()
    for name in (*sd.OPEN_HOLE_FILES, "LICENSE-2D_ALDIC-data.txt", "README.md"):
        assert (folder / name).is_file(), name
    assert "Jin Yang" in (folder / "LICENSE-2D_ALDIC-data.txt").read_text()


def test_sample_data_dir_wheel_then_source_layout(tmp_path):
    # wheel: <site-packages>/napari_aldic/sample_data/<name>
    pkg = tmp_path / "site" / "napari_aldic"
    (pkg / "sample_data" / "open_hole_tension").mkdir(parents=True)
    assert sd.sample_data_dir(package_dir=pkg) == pkg / "sample_data" / "open_hole_tension"
    # editable install: <repo>/src/napari_aldic -> <repo>/sample_data/<name>
    src_pkg = tmp_path / "repo" / "src" / "napari_aldic"
    src_pkg.mkdir(parents=True)
    top = tmp_path / "repo" / "sample_data" / "open_hole_tension"
    top.mkdir(parents=True)
    assert sd.sample_data_dir(package_dir=src_pkg) == top
    with pytest.raises(FileNotFoundError, match="open_hole_tension"):
        sd.sample_data_dir(package_dir=tmp_path / "nowhere" / "a" / "b")


def test_sample_data_and_cli_import_no_gui_modules():
    code = (
        "import sys; import napari_aldic._sample_data, napari_aldic.cli;"
        "bad = [m for m in ('napari', 'qtpy', 'PyQt5', 'PyQt6', 'PySide2', 'PySide6',"
        " 'magicgui', 'vispy', 'matplotlib') if m in sys.modules];"
        "print('BAD', bad) if bad else print('OK')"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "OK", out.stdout


# ----------------------------------------------------------------- manifest
def test_manifest_is_valid_and_lists_the_samples():
    import npe2
    path = REPO / "napari.yaml"
    pm = npe2.PluginManifest.from_file(path)  # schema validation
    pm.validate_imports()  # every python_name resolves
    assert pm.name == "napari-aldic" and pm.display_name == "napari-aldic"
    commands = {c.id: c.python_name for c in pm.contributions.commands}
    samples = {s.command for s in pm.contributions.sample_data}
    assert samples == {"napari-aldic.make_translation_pair", "napari-aldic.make_crack_pair",
                       "napari-aldic.make_strain_sequence", "napari-aldic.make_plate_with_hole",
                       "napari-aldic.load_open_hole_pair", "napari-aldic.load_crack_sequence"}
    assert samples <= set(commands)
    assert all(commands[c].startswith("napari_aldic._sample_data:") for c in samples)
    # the package carries the same manifest (symlink to the top-level file)
    inside = REPO / "src" / "napari_aldic" / "napari.yaml"
    assert inside.resolve() == path.resolve()


def test_npe2_cli_validates_manifest():
    exe = Path(sys.executable).parent / "npe2"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "npe2"]
    proc = subprocess.run(cmd + ["validate", str(REPO / "napari.yaml")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "valid" in proc.stdout


def test_strain_sequence_sample_matches_its_truth():
    from napari_aldic._sample_data import make_strain_sequence
    from napari_aldic.engine import track

    (stack, kw, kind), = make_strain_sequence(n_frames=3, size=160)
    assert kind == "image" and stack.shape == (3, 160, 160) and stack.dtype == np.uint8
    truth = kw["metadata"]["truth"]["frames"][2]
    seq = track(stack, step=12)
    res = seq[2]
    X = res.x - truth["center"][0]
    Y = res.y - truth["center"][1]
    u_true = truth["t"][0] + truth["exx"] * X
    v_true = truth["t"][1] + truth["eyy"] * Y
    v = res.valid
    assert v.mean() > 0.7
    assert np.abs(res.u[v] - u_true[v]).max() < 0.02
    assert np.abs(res.v[v] - v_true[v]).max() < 0.02


def test_plate_with_hole_sample_and_kirsch_field():
    from napari_aldic._sample_data import make_plate_with_hole
    from napari_aldic.engine import correlate, synthetic

    (stack, kw, _), (roi, _, kind) = make_plate_with_hole(size=256)
    assert kind == "labels" and roi.shape == stack.shape[1:]
    t = kw["metadata"]["truth"]
    field = synthetic.PlateWithHole(center=tuple(t["center"]), radius=t["radius"],
                                    amplitude=t["amplitude"], nu=t["nu"], t=tuple(t["t"]))
    # far from the hole the Kirsch field is uniform uniaxial strain
    kappa = (3 - field.nu) / (1 + field.nu)
    g = field.gradient(np.array([5000.0]), np.array([4000.0]))
    assert g[0][0] == pytest.approx(field.amplitude * (kappa + 1) / 2, rel=1e-3)
    assert g[3][0] == pytest.approx(field.amplitude * (kappa - 3) / 2, rel=1e-3)
    # the analysed field follows the Kirsch truth up to the hole
    res = correlate(stack[0], stack[1], roi=roi > 0, step=8, method="aldic")
    ut, vt = field.displacement(res.x, res.y)
    v = res.valid
    assert v.mean() > 0.85
    assert np.sqrt(np.mean((res.u[v] - ut[v]) ** 2 + (res.v[v] - vt[v]) ** 2)) < 0.02


def test_crack_sequence_sample_is_the_shipped_crop_and_the_crack_opens():
    [(stack, kwargs, kind)] = sd.load_crack_sequence()
    assert kind == "image" and stack.shape == (6, 384, 384) and stack.dtype == np.uint8
    assert "BSD-3-Clause" in kwargs["metadata"]["description"]
    folder = sd.sample_data_dir("crack_sequence")
    for name in (sd.CRACK_FILE, "LICENSE-2D_ALDIC-data.txt", "README.md"):
        assert (folder / name).is_file(), name
    assert "Jin Yang" in (folder / "LICENSE-2D_ALDIC-data.txt").read_text()
    total = sum(p.stat().st_size for p in folder.parent.rglob("*") if p.is_file())
    assert total < 2_000_000  # every shipped sample together
    # the crack opens near the notch (v jumps across it) and not far from it
    roi = np.zeros(stack.shape[1:], bool)
    roi[150:330, 40:140] = True
    roi[150:330, 300:378] = True
    res = correlate(stack[0], stack[5], roi=roi, subset=25, step=10)
    ok = res.valid

    def v_at(x, y):
        near = ok & (np.abs(res.x - x) <= 5) & (np.abs(res.y - y) <= 5)
        assert near.any(), (x, y)
        return float(np.median(res.v[near]))

    # x = 63: the trusted nodes nearest the notch (those at x = 73, whose subsets
    # reach the crack's tip region, are flagged static or uncertain since issue 22)
    opening = v_at(62, 250) - v_at(62, 205)
    assert opening > 3.0
    assert abs(v_at(330, 250) - v_at(330, 205)) < 0.4 * opening
    assert -62 < v_at(330, 205) < -50  # the specimen moved ~57 px up


def test_crack_sequence_crop_matches_the_original(shared_data):
    import tifffile

    [(stack, _, _)] = sd.load_crack_sequence()
    original = tifffile.imread(shared_data / "crack_sequence" / "crack_sequence.tif")
    for k, source in enumerate((0, 2, 4, 6, 8, 10)):
        crop = original[source, 360:744, 200:584].astype(float)
        expect = np.clip(np.rint((crop - 5000.0) * 255.0 / 60535.0), 0, 255)
        np.testing.assert_array_equal(stack[k], expect)
