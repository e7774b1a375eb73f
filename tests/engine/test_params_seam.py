"""One rule for parameters: explicit keyword arguments override ``params``, always;
every default written once (DICParams, StrainParams)."""

from __future__ import annotations

import dataclasses
import inspect

import numpy as np
import pytest

from napari_aldic.engine import (
    DICError,
    DICParams,
    Settings,
    StrainParams,
    compute_strain,
    correlate,
    synthetic as S,
    track,
)

FAST = dict(step=16, search=6)


@pytest.fixture(scope="module")
def pair():
    return S.speckle_pair((96, 96), S.Translation(0.3, 0.0), seed=5)


def test_explicit_argument_equal_to_the_default_overrides_params(pair):
    # 0.1 dropped subset=31 because it equals DICParams' default: params' 41 was used
    res = correlate(*pair, params=DICParams(subset=41, step=16), subset=31, search=6)
    assert res.params.subset == 31 and res.params.step == 16 and res.params.search == 6
    res = correlate(*pair, params=DICParams(subset=21, method="aldic", **FAST),
                    method="local")
    assert res.params.method == "local"


def test_track_applies_subset_and_kwargs_given_with_params(pair):
    stack = np.stack([pair[0], pair[1]])
    # 0.1 ignored subset and **kwargs as soon as params was given
    seq = track(stack, params=DICParams(subset=41, step=16), subset=21, search=6)
    assert seq.params.subset == 21 and seq.params.search == 6 and seq[1].params.subset == 21


def test_combine_is_the_one_rule():
    base = DICParams(subset=41, step=12)
    assert DICParams.combine(None, {}, subset=None, step=None) == DICParams()
    assert DICParams.combine(base, {}, subset=None) is base
    assert DICParams.combine(base, {"search_max": None}, subset=31).subset == 31
    # a dict of the fields (e.g. from a JSON file) is read as DICParams; explicit still wins
    assert DICParams.combine({"subset": 41}, {}, subset=31) == DICParams(subset=31)
    with pytest.raises(TypeError, match="DICParams"):
        DICParams.combine([("subset", 31)], {})


def test_defaults_are_written_once():
    # the engine's signatures take their defaults from the parameter types
    for fn in (correlate, track):
        sig = inspect.signature(fn).parameters
        assert sig["subset"].default is None and sig["step"].default is None
    strain = inspect.signature(compute_strain).parameters
    assert {k: strain[k].default for k in ("window", "method", "measure")} == \
        dataclasses.asdict(StrainParams())
    assert Settings(DICParams()).strain_options() == StrainParams().to_dict()


def test_the_cli_defaults_come_from_the_parameter_types():
    from napari_aldic.cli.parser import build_parser

    parser = build_parser()
    demo = parser.parse_args(["demo"])
    assert (demo.subset, demo.step, demo.method) == (DICParams.subset, DICParams.step,
                                                      DICParams.method)
    nf = parser.parse_args(["noise-floor", "a.tif", "b.tif"])
    assert nf.window == StrainParams.window


def test_errors_are_typed_with_a_code_and_fields():
    with pytest.raises(DICError) as info:
        DICParams(subset=30)
    assert info.value.code == "not_odd" and info.value.fields == {"name": "subset",
                                                                  "value": 30}
    assert isinstance(info.value, ValueError)  # 0.1 callers catching ValueError still do
    with pytest.raises(DICError, match="differs from image shape") as info:
        img = np.random.default_rng(0).random((64, 64))
        correlate(img, img, roi=np.ones((32, 32), bool))
    assert info.value.code == "shape_mismatch" and info.value.fields["what"] == "roi"
