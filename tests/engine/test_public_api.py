"""The engine's public surface after the restructuring: curated names, old paths, Settings."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import napari_aldic.engine as engine
from napari_aldic.engine import DICParams, Settings, Units


def test_public_api_is_curated_and_importable():
    # deliberate additions since the split: tiled pairs, measurement quality (issue 12),
    # SEM corrections (issue 27), input-file errors (issue 23), volumes and their tracking
    # (issue 28), precompiling the kernels in parallel (issue 25)
    assert 15 <= len(engine.__all__) <= 52
    for name in engine.__all__:
        assert getattr(engine, name) is not None
    # algorithm internals are not part of the top-level API
    for internal in ("prefilter", "sample", "SplineImage", "as_gray_float"):
        assert internal not in engine.__all__


def test_the_0_1_shims_are_retired():
    """Names of 0.1 moved into subpackages, and save_params/load_params/load_settings
    (write_settings/read_settings and Settings replace them), are gone (issue 24)."""
    import napari_aldic.engine.io as io

    for name in ("export_csv", "prefilter", "plot_displacement", "save_params",
                 "load_params", "load_settings"):
        assert not hasattr(engine, name), name
    for name in ("save_params", "load_params", "load_settings"):
        assert not hasattr(io, name), name
    assert callable(io.export_csv) and callable(engine.read_settings)


def test_old_user_imports_keep_working_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        from napari_aldic.engine import (  # noqa: F401
            compute_strain,
            correlate,
            export_result,
            load_result,
            synthetic,
            track,
        )
    assert callable(synthetic.speckle_pair)


def test_unknown_engine_attribute_raises_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        engine.nonexistent  # noqa: B018


def test_settings_round_trip_and_one_place_of_validation():
    s = Settings(DICParams(subset=25, step=6), units=Units(pixel_size=0.5, unit="um"),
                 strain={"window": 7, "method": "plane_fit", "measure": "infinitesimal"},
                 tracking={"reference": "incremental"})
    back = Settings.from_dict(s.to_dict())
    assert back.params == s.params and back.units == s.units
    assert back.strain == s.strain and back.tracking == s.tracking
    bad = s.to_dict()
    bad["strain"]["window"] = 6
    with pytest.raises(ValueError, match="odd"):
        Settings.from_dict(bad)
    bad = s.to_dict()
    bad["tracking"] = {"reference": "sideways"}
    with pytest.raises(ValueError, match="sideways"):
        Settings.from_dict(bad)
    bad = s.to_dict()
    bad["bogus"] = {}
    with pytest.raises(ValueError, match="unknown section"):
        Settings.from_dict(bad)


def test_one_reader_names_the_file(tmp_path):
    from napari_aldic.engine.io import FrameSource, natural_key, read_image

    with pytest.raises(FileNotFoundError, match="nope.tif"):
        read_image(tmp_path / "nope.tif")
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not an image")
    with pytest.raises(ValueError, match="junk.png"):
        read_image(junk)
    import tifffile

    for k in (10, 2, 1):
        tifffile.imwrite(tmp_path / f"img_{k}.tif", np.full((8, 9), k, np.uint8))
    junk.unlink()
    src = FrameSource(tmp_path)
    assert src.shape == (3, 8, 9)
    assert [int(src[k][0, 0]) for k in range(3)] == [1, 2, 10]  # natural order
    assert sorted(["a10", "a2"], key=natural_key) == ["a2", "a10"]


def test_every_public_name_has_one_lazy_home():
    """``__all__`` (curated, by role) and the lazy import table of
    ``engine/__init__`` name the same things: a name missing from the table
    would fail at first use, one missing from ``__all__`` would be unlisted."""
    table = [n for names in engine._WHERE.values() for n in names]
    assert len(table) == len(set(table))
    assert set(table) | {"io", "probes", "sem", "synthetic", "viz"} == set(engine.__all__)
