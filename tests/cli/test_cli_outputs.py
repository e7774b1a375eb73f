"""What the command line tells and draws: the demo's warm-up apart from the
analysis speed, ``run --plot`` in the units given, and ``export`` saying when
its unit options replace the units stored in a result."""

from __future__ import annotations

import re

import pytest
import tifffile

from napari_aldic.engine import load_result, synthetic as S


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """A 128 x 96 pair moved 4 px down (v one-signed) and stretched along x."""
    folder = tmp_path_factory.mktemp("pair")
    field = S.Affine.strain_rotation(exx=0.01, center=(48, 64), t=(0.2, -4.0))
    ref, dfm = S.speckle_pair((128, 96), field, seed=5)
    for name, img in (("ref.tif", ref), ("def.tif", dfm)):
        tifffile.imwrite(folder / name, img)
    return folder


def test_demo_reports_the_warm_up_apart_from_the_analysis(run_cli, tmp_path):
    rc, out, err = run_cli(["demo", "--out", tmp_path, "--size", 96, "--step", 12])
    assert rc == 0, err
    lines = out.splitlines()
    warm = next(i for i, t in enumerate(lines) if "warm-up:" in t)
    analysis = next(i for i, t in enumerate(lines) if "analysis:" in t)
    assert warm < analysis
    assert re.search(r"warm-up: [0-9.]+ s", lines[warm])
    # the speed line is the analysis alone: the time stored in the result
    res = load_result(tmp_path / "result.npz")
    shown = float(re.search(r"([0-9.]+) s \(", lines[analysis]).group(1))
    assert shown == pytest.approx(res.meta["timing"]["total"], abs=1e-3)


def test_run_plot_draws_in_the_units_given(run_cli, tmp_path, pair, monkeypatch):
    import napari_aldic.cli.run as run_module
    from napari_aldic.engine.viz import displacement_figure

    figures = []
    real = run_module.plot_displacement

    def plot(res, path, **kw):
        figures.append(displacement_figure(res, **{k: v for k, v in kw.items() if k != "dpi"}))
        return real(res, path, **kw)

    monkeypatch.setattr(run_module, "plot_displacement", plot)
    rc, out, err = run_cli(["run", pair / "ref.tif", pair / "def.tif", "-o", tmp_path / "r.npz",
                         "--subset", 21, "--step", 8, "--plot", "--pixel-size", 0.05,
                         "--unit", "mm"])
    assert rc == 0, err
    assert (tmp_path / "r.png").is_file() and len(figures) == 1
    fig = figures[0]
    maps = [ax for ax in fig.get_axes() if ax.get_label() != "<colorbar>"]
    bars = [ax for ax in fig.get_axes() if ax.get_label() == "<colorbar>"]
    assert maps[0].get_xlabel() == "x (mm)" and bars[1].get_ylabel() == "v (mm)"
    assert "Local DIC" in fig.get_suptitle()
    res = load_result(tmp_path / "r.npz")
    v = res.v[res.valid] * 0.05
    lo, hi = maps[1].images[-1].get_clim()
    assert v.min() - 1e-9 <= lo < hi <= v.max() + 1e-9  # the data's range, not +-max|v|


def test_export_says_when_unit_options_replace_the_stored_units(run_cli, tmp_path, pair):
    rc, _, err = run_cli(["run", pair / "ref.tif", pair / "def.tif", "-o", tmp_path / "r.npz",
                       "--subset", 21, "--step", 16, "--pixel-size", 0.05, "--unit", "mm"])
    assert rc == 0, err
    rc, out, err = run_cli(["export", tmp_path / "r.npz", "--to", "csv", "-o", tmp_path / "a",
                         "--pixel-size", 0.5, "--unit", "um", "--no-strain"])
    assert rc == 0
    warning = [t for t in err.splitlines() if "warning" in t]
    assert len(warning) == 1
    assert "--pixel-size, --unit override the units stored in the result" in warning[0]
    assert "0.05 mm" in warning[0] and "0.5 um" in warning[0]
    assert "1 px = 0.5 um" in out
    # the same units, or a frame interval the result did not have: nothing replaced
    for extra in (["--pixel-size", 0.05, "--unit", "mm"], ["--frame-interval", 2]):
        rc, out, err = run_cli(["export", tmp_path / "r.npz", "--to", "csv", "-o",
                             tmp_path / "b", "--no-strain", *extra])
        assert rc == 0 and "warning" not in err, err
    assert "1 px = 0.05 mm; frame interval 2 s" in out  # stored units kept, interval added


def test_option_help_states_the_engine_defaults(run_cli):
    from napari_aldic.engine import DICParams

    rc, out, _ = run_cli(["run", "--help"])
    assert rc == 0
    text = " ".join(out.split("options:", 1)[1].split())
    defaults = DICParams()
    for option in ("subset", "step", "search", "method", "interpolation"):
        helps = re.search(rf"--{option} \S+ (.*?)(?= --|$)", text).group(1)
        stated = re.search(r"default (\w+)", helps).group(1)
        assert stated == str(getattr(defaults, option)), (option, helps)
