"""Every bad input gets a named error that says what is wrong, and which file
(issue 11, section 3).

One table, :data:`CASES`: each case builds a bad input in a temporary folder,
feeds it to the engine and names the error type and a pattern its message
must match. A case that works on a file records it in ``ctx.file``; the
message must then name that file (and the test checks the pattern too).
User text in written files (units, names) is tested in test_user_text_exports.py,
the command line's one-line errors in tests/cli/test_cli_errors.py.
"""

from __future__ import annotations

import io
import json
import math
import re
import types
import zipfile
from pathlib import Path

import numpy as np
import pytest

from napari_aldic.engine import (
    DICParams,
    ExportError,
    compute_strain,
    correlate,
    export_result,
    load_result,
    load_run,
    synthetic as S,
    track,
)
from napari_aldic.engine.io import load_mat, open_stack, read_settings

SHAPE = (128, 128)
#: case name -> (function(ctx), error type, regex the message must match)
CASES: dict[str, tuple] = {}


def case(name: str, error: type, pattern: str):
    def register(fn):
        assert name not in CASES, name
        CASES[name] = (fn, error, pattern)
        return fn
    return register


# ------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def pair():
    return S.speckle_pair(SHAPE, S.Translation(0.4, -0.2), seed=1)


@pytest.fixture(scope="module")
def result(pair):
    """A 12 x 12 node result (144 nodes) with its ROI."""
    res = correlate(*pair, subset=31, step=8)
    assert len(res) == 144
    return res


@pytest.fixture
def ctx(tmp_path, pair, result):
    saved = result.save(tmp_path / "good.npz")
    return types.SimpleNamespace(tmp=tmp_path, pair=pair, res=result, good=saved, file=None)


# ------------------------------------------------------------------ helpers
def _members(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as zf:
        return {i.filename: zf.read(i) for i in zf.infolist()}


def _npy(arr) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.asarray(arr), allow_pickle=False)
    return buf.getvalue()


def _npy_claiming(shape, descr="<f8") -> bytes:
    """A .npy member whose header claims ``shape`` but that holds 16 bytes:
    what a decompression bomb declares."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False,
                                               "shape": tuple(shape)})
    return buf.getvalue() + bytes(16)


def _edited(ctx, name="bad.npz", doc=None, **members) -> Path:
    """A copy of the good result file with members replaced (bytes or
    arrays; None removes one) and keys of its JSON header changed (``doc``)."""
    parts = _members(ctx.good)
    if doc is not None:
        header = json.loads(str(np.load(io.BytesIO(parts["header.npy"]))))
        header.update(doc)
        parts["header.npy"] = _npy(np.array(json.dumps(header)))
    for k, v in members.items():
        if v is None:
            parts.pop(f"{k}.npy")
        else:
            parts[f"{k}.npy"] = v if isinstance(v, bytes) else _npy(v)
    path = ctx.tmp / name
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for k, data in parts.items():
            zf.writestr(k, data)
    ctx.file = path
    return path


def _params_file(ctx, text: str) -> Path:
    path = ctx.tmp / "bad_params.json"
    path.write_text(text)
    ctx.file = path
    return path


# =================================================================== parameter files
PARAM_FILES = {
    "seeds_short_point": ('{"seeds": [[1]]}', r"seed 0 .* two numbers"),
    "seeds_number": ('{"seeds": 5}', r"seeds=5 must be a list of \(x, y\) points"),
    "seeds_text": ('{"seeds": "12"}', r"seeds='12' must be a list"),
    "seeds_three_values": ('{"seeds": [[1, 2, 3]]}', r"seed 0 .* two numbers"),
    "seeds_text_coordinate": ('{"seeds": [[1, "a"]]}', r"seed 0 y='a' must be a number"),
    "seeds_nan": ('{"seeds": [[NaN, 3]]}', r"seed 0 x=nan must be a finite number"),
    "n_threads_text": ('{"n_threads": "4"}', r"n_threads='4' must be an integer or None, not str"),
    "mu_text": ('{"mu": "0.1"}', r"mu='0.1' must be a number, not str"),
    "subset_text": ('{"subset": "31"}', r"subset='31' must be an integer, not str"),
    "search_max_text": ('{"search_max": "40"}', r"search_max='40' must be an integer"),
    "tol_bool": ('{"tol": true}', r"tol=True must be a number, not bool"),
    "method_number": ('{"method": 3}', r"method=3 must be 'local' or 'aldic'"),
    "refine_number": ('{"refine": 5}', r"refine=5 must be None, 'light'"),
    "warp_text": ('{"second_order_warp": "yes"}', r"second_order_warp='yes' must be True"),
    "smooth_text": ('{"smooth": "fast"}', r"smooth='fast' must be 'auto' or a number"),
    "zncc_rel_nan": ('{"zncc_rel": NaN}', r"zncc_rel=nan must be a finite number"),
    "search_max_inf": ('{"search_max": Infinity}', r"search_max=inf must be a finite integer"),
    "units_number": ('{"params": {}, "units": 5}', r"'units' section must be a JSON object"),
    "units_zero": ('{"params": {}, "units": 0}', r"'units' section must be a JSON object"),
    "unit_number": ('{"params": {}, "units": {"unit": 5}}', r"unit=5 must be a non-empty name"),
    "frame_interval_nan": ('{"params": {}, "units": {"frame_interval": NaN}}',
                           r"frame_interval=nan must be a positive number"),
    "strain_window_text": ('{"params": {}, "strain": {"window": "5"}}',
                           r"strain window '5' must be a whole number"),
    "stride_text": ('{"params": {}, "tracking": {"stride": "2"}}',
                    r"frame stride '2' must be a whole number"),
    "params_list": ('{"format": "napari-aldic-settings", "params": [31]}',
                    r"must be a dictionary \(JSON object\)"),
    "params_number": ('{"params": 31, "units": {}}', r"must be a dictionary|Unknown DIC"),
    "top_level_nan": ("NaN", r"must hold a JSON object"),
}


def _param_file_case(text):
    return lambda ctx: read_settings(_params_file(ctx, text))


for _name, (_text, _pattern) in PARAM_FILES.items():
    case(f"params_file_{_name}", ValueError, _pattern)(_param_file_case(_text))


# =================================================================== NaN / inf everywhere
INT_FIELDS = ("subset", "step", "search", "search_max", "init_spacing", "anchor_spacing",
              "max_iter", "admm_max_iter", "n_threads")
FLOAT_FIELDS = ("tol", "zncc_min", "zncc_rel", "min_component", "mu", "beta", "smooth",
                "admm_tol")


def _param_case(field, value):
    return lambda ctx: DICParams(**{field: value})


for _field in INT_FIELDS + FLOAT_FIELDS:
    for _label, _value in (("nan", math.nan), ("inf", math.inf), ("minus_inf", -math.inf)):
        case(f"param_{_field}_{_label}", ValueError,
             rf"Invalid DIC parameter: {_field}=-?(nan|inf) must be .*finite")(
            _param_case(_field, _value))
for _label, _value in (("nan", math.nan), ("inf", math.inf)):
    case(f"param_seeds_{_label}", ValueError, r"seed 1 y=-?(nan|inf) must be a finite")(
        _param_case("seeds", [(10, 20), (30, _value)]))


def _stack(ctx):
    return np.stack([ctx.pair[0], ctx.pair[1]])


#: calls with a bad argument: name -> (error type, pattern, function(ctx))
CALLS = {
    "param_seeds_in_correlate_nan": (ValueError, r"seed 0 x=nan must be a finite number",
                                     lambda c: correlate(*c.pair, init="seeds",
                                                         seeds=[(math.nan, 40)])),
    "param_zncc_rel_in_track_nan": (ValueError, r"zncc_rel=nan",
                                    lambda c: track(_stack(c), zncc_rel=math.nan)),
    # unbounded values
    "max_iter_huge": (ValueError, r"max_iter=1000000000 must be between 1 and 10000",
                      lambda c: DICParams(max_iter=10**9)),
    "tol_below_float32_resolution": (ValueError, r"tol=1e-300 must be in \[1e-06, 1\) pixel",
                                     lambda c: DICParams(tol=1e-300)),
    "admm_max_iter_huge": (ValueError, r"admm_max_iter=100000 must be between 1 and 1000",
                           lambda c: DICParams(admm_max_iter=100_000)),
    "strain_window_beyond_lattice": (
        ValueError, r"window=10001 nodes is wider than the result's node lattice \(12 x 12 "
                    r"nodes\)", lambda c: compute_strain(c.res, window=10001)),
    "strain_window_fem_beyond_lattice": (
        ValueError, r"window=99 nodes is wider",
        lambda c: compute_strain(c.res, window=99, method="fem")),
    # wrong types
    "strain_of_an_array": (TypeError, r"compute_strain needs a DICResult .* not ndarray",
                           lambda c: compute_strain(np.zeros(5))),
    "strain_of_a_sequence": (TypeError, r"not SequenceResult.*seq\[k\]",
                             lambda c: compute_strain(track(_stack(c), subset=31, step=32))),
    "strain_of_a_path": (TypeError, r"not str.*load_result",
                         lambda c: compute_strain(str(c.good))),
    "strain_window_text": (ValueError, r"window='5' must be an odd number",
                           lambda c: compute_strain(c.res, window="5")),
    "guess_text": (TypeError, r"guess must be a DICResult .* not str",
                   lambda c: correlate(*c.pair, guess="previous")),
    "guess_array": (TypeError, r"guess must be a DICResult .* not ndarray",
                    lambda c: correlate(*c.pair, guess=np.zeros((144, 2)))),
    "track_no_frames": (ValueError, r"frames=\[\] .* frame 0 and at least one",
                        lambda c: track(_stack(c), frames=[])),
    "track_one_frame": (ValueError, r"frames=\[0\] .* frame 0 and at least one",
                        lambda c: track(_stack(c), frames=[0])),
    "track_frames_text": (TypeError, r"frames='all' must be a list of frame numbers",
                          lambda c: track(_stack(c), frames="all")),
    "track_frames_fraction": (TypeError, r"frame 1.5 .* whole number",
                              lambda c: track(_stack(c), frames=[0, 1.5])),
}
for _name, (_error, _pattern, _call) in CALLS.items():
    case(_name, _error, _pattern)(_call)


# =================================================================== images
@case("float64_beyond_float32", ValueError,
      r"reference image holds values up to [0-9.]+e\+\d+, beyond the float32 range")
def _(ctx):
    correlate(ctx.pair[0].astype(np.float64) * 1e300 / 255, ctx.pair[1])


@case("float64_below_float32", ValueError, r"deformed image holds only values below")
def _(ctx):
    correlate(ctx.pair[0], ctx.pair[1].astype(np.float64) * 1e-300)


# =================================================================== result files
@case("npz_zero_bytes", ValueError, r"the file is empty \(0 bytes\)")
def _(ctx):
    ctx.file = ctx.tmp / "empty.npz"
    ctx.file.write_bytes(b"")
    load_result(ctx.file)


@case("npz_text_file", ValueError, r"it is a text file, not an \.npz archive")
def _(ctx):
    ctx.file = ctx.tmp / "notes.npz"
    ctx.file.write_text("u,v\n1,2\n")
    load_result(ctx.file)


@case("npz_single_array", ValueError, r"single NumPy array \(\.npy\)")
def _(ctx):
    ctx.file = ctx.tmp / "array.npz"
    ctx.file.write_bytes(_npy(np.arange(5)))
    load_result(ctx.file)


@case("npz_truncated", ValueError, r"truncated or damaged")
def _(ctx):
    ctx.file = ctx.tmp / "cut.npz"
    data = ctx.good.read_bytes()
    ctx.file.write_bytes(data[: len(data) // 2])
    load_result(ctx.file)


@case("npz_damaged_data", ValueError, r"array 'u' is damaged")
def _(ctx):
    path = _edited(ctx, u=np.linspace(0, 1, 144))
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo("u.npy")
        start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    data = bytearray(path.read_bytes())
    for i in range(start + 20, start + info.compress_size - 4):
        data[i] ^= 0x5A  # scramble the compressed payload, keep the zip directory
    path.write_bytes(bytes(data))
    load_result(path)


@case("npz_a_folder", ValueError, r"it is a folder")
def _(ctx):
    ctx.file = ctx.tmp / "folder.npz"
    ctx.file.mkdir()
    load_result(ctx.file)


_SIDE = 1 << 20  # the largest image side a header may give: 1 TiB of pixels
_NODE_ARRAYS = ("x", "y", "u", "v", "dudx", "dudy", "dvdx", "dvdy", "valid", "zncc", "reason",
                "iterations", "grid_ix", "grid_iy")
_PICKLE = io.BytesIO()
np.save(_PICKLE, np.array([{"a": 1}], dtype=object), allow_pickle=True)
#: edited result files: name -> (changes for _edited, pattern of the message)
NPZ_EDITS = {
    "u_5_entries": (dict(u=np.zeros(5)), r"array 'u' has shape \(5,\) but 'x' has 144 entries"),
    "header_4000_for_128": (dict(doc={"image_shape": [4000, 4000]}),
                            r"its ROI holds \(2048,\) uint8 but image_shape 4000 x 4000 .* "
                            r"needs \(2000000,\)"),
    "header_smaller_than_nodes": (dict(doc={"image_shape": [64, 64]}, roi_packed=None),
                                  r"node coordinates .* outside the 64 x 64 image of its header"),
    "bomb_one_array": (dict(u=_npy_claiming((10**10,))),
                       r"array 'u' has shape \(10000000000,\) but 'x' has 144 entries"),
    "bomb_every_node_array": ({k: _npy_claiming((10**9,)) for k in _NODE_ARRAYS},
                              r"declares 1000000000 nodes for a 128 x 128 image"),
    "bomb_roi": (dict(roi_packed=_npy_claiming((10**11,), "|u1")),
                 r"its ROI holds \(100000000000,\) uint8"),
    "bomb_huge_image": (dict(doc={"image_shape": [_SIDE, _SIDE]},
                             roi_packed=_npy_claiming(((_SIDE * _SIDE) // 8,), "|u1")),
                        r"would need .* GiB, more than the memory available now"),
    "bomb_elements": (dict(elements=_npy_claiming((10**9, 4), "<i8")),
                      r"array 'elements' has shape \(1000000000, 4\)"),
    "bomb_header": (dict(header=_npy_claiming((), "<U100000000")),
                    r"header is not a text of at most 64 MB"),
    "missing_x": (dict(x=None), r"incomplete: array\(s\) \['x'\] are missing"),
    "pickled_objects": (dict(meta=_PICKLE.getvalue()),
                        r"array 'meta' holds Python objects \(pickled"),
    "text_coordinates": (dict(x=np.array(["abc"] * 144)),
                         r"array 'x' has dtype <U3; expected numbers"),
    "no_header": (dict(header=None), r"not a napari-aldic result file \(no header\)"),
    "header_not_json": (dict(header=np.array("{not json")), r"header is not valid JSON"),
    "header_bad_params": (dict(doc={"params": {"subset": 30}}),
                          r"parameters in its header are invalid: .*subset=30"),
    "header_bad_shape": (dict(doc={"image_shape": [128]}), r"image_shape \[128\] in its header"),
}


def _npz_case(changes):
    return lambda ctx: load_result(_edited(ctx, **changes))


for _name, (_changes, _pattern) in NPZ_EDITS.items():
    case(f"npz_{_name}", ValueError, _pattern)(_npz_case(_changes))


@case("npz_lattice_index_out_of_range", ValueError, r"'grid_ix' points outside the 12")
def _(ctx):
    ix = ctx.res.grid_ix.copy()
    ix[3] = 40
    load_result(_edited(ctx, grid_ix=ix))


@case("export_npz_missing_x", ValueError, r"incomplete: array\(s\) \['x'\] are missing")
def _(ctx):
    export_result(_edited(ctx, x=None), ctx.tmp / "out.csv")


@case("export_text_npz", ValueError, r"it is a text file")
def _(ctx):
    ctx.file = ctx.tmp / "notes.npz"
    ctx.file.write_text("not a result")
    export_result(ctx.file, ctx.tmp / "out.vtu")


@case("save_on_full_disk", ExportError, r"no space left on the device")
def _(ctx):
    import errno

    ctx.file = ctx.tmp / "full.npz"
    real = np.savez_compressed

    def full(fh, *args, **kwargs):
        fh.write(b"PK")
        raise OSError(errno.ENOSPC, "No space left on device")

    np.savez_compressed = full
    try:
        ctx.res.save(ctx.file)
    finally:
        np.savez_compressed = real


# =================================================================== MATLAB files
@case("mat_without_frames", ValueError, r"has no 'frames'")
def _(ctx):
    import scipy.io as sio

    from napari_aldic.engine.io import export_mat

    full = export_mat(ctx.res, ctx.tmp / "full.mat")
    d = {k: v for k, v in sio.loadmat(full).items() if not k.startswith("__")}
    d.pop("frames")
    ctx.file = ctx.tmp / "noframes.mat"
    sio.savemat(ctx.file, d)
    load_mat(ctx.file)


@case("mat_text_file", ValueError, r"not a MATLAB file")
def _(ctx):
    ctx.file = ctx.tmp / "notes.mat"
    ctx.file.write_text("x = 1\n")
    load_mat(ctx.file)


@case("mat_frame_missing_field", ValueError, r"frames\(1\) has no field .u_px.")
def _(ctx):
    import scipy.io as sio

    from napari_aldic.engine.io import export_mat

    full = export_mat(ctx.res, ctx.tmp / "full.mat")
    d = {k: v for k, v in sio.loadmat(full).items() if not k.startswith("__")}
    st = d["frames"]
    names = [n for n in st.dtype.names if n != "u_px"]
    new = np.empty(st.shape, dtype=[(n, object) for n in names])
    for n in names:
        new[0, 0][n] = st[0, 0][n]
    d["frames"] = new
    ctx.file = ctx.tmp / "nou.mat"
    sio.savemat(ctx.file, d)
    load_mat(ctx.file)


@case("export_mat_without_frames", ValueError, r"has no 'frames'")
def _(ctx):
    import scipy.io as sio

    ctx.file = ctx.tmp / "other.mat"
    sio.savemat(ctx.file, {"format": "napari-aldic-mat", "params_json": "{}",
                           "image_shape": np.array([[128, 128]])})
    export_result(ctx.file, ctx.tmp / "out.csv")


# =================================================================== run folders
def _run_folder(ctx) -> Path:
    folder = ctx.tmp / "run"
    stack = np.stack([ctx.pair[0], ctx.pair[1], ctx.pair[1]])
    track(stack, subset=31, step=32, out_dir=folder)
    ctx.stack = stack
    return folder


@case("run_folder_corrupt_manifest", ValueError, r"cannot read .*: ")
def _(ctx):
    folder = _run_folder(ctx)
    ctx.file = folder / "sequence.json"
    ctx.file.write_text('{"frames": [0, 1, 2')
    load_run(folder)


@case("resume_corrupt_manifest", ValueError, r"sequence\.json")
def _(ctx):
    folder = _run_folder(ctx)
    ctx.file = folder / "sequence.json"
    ctx.file.write_text('{"frames": [0, 1, 2')
    track(ctx.stack, subset=31, step=32, out_dir=folder)


@case("resume_corrupt_frame_file", ValueError, r"truncated or damaged")
def _(ctx):
    folder = _run_folder(ctx)
    ctx.file = folder / "frame_00001.npz"
    data = ctx.file.read_bytes()
    ctx.file.write_bytes(data[: len(data) // 3])
    track(ctx.stack, subset=31, step=32, out_dir=folder)


@case("load_run_zero_byte_frame", ValueError, r"the file is empty")
def _(ctx):
    folder = _run_folder(ctx)
    ctx.file = folder / "frame_00002.npz"
    ctx.file.write_bytes(b"")
    load_run(folder)


# =================================================================== stacks
def _tiff_stack(ctx, name="stack.tif", n=3) -> Path:
    import tifffile

    rng = np.random.default_rng(0)
    path = ctx.tmp / name
    with tifffile.TiffWriter(path) as tw:  # one IFD before each page, like cameras write
        for _ in range(n):
            tw.write((rng.random(SHAPE) * 4000).astype(np.uint16), contiguous=False,
                     metadata=None, photometric="minisblack")
    return path


@case("tiff_truncated_last_page", ValueError, r"truncated: page 2 of 3")
def _(ctx):
    ctx.file = _tiff_stack(ctx)
    data = ctx.file.read_bytes()
    ctx.file.write_bytes(data[:-5000])
    open_stack(ctx.file)


@case("tiff_truncated_pages_lost", ValueError, r"truncated: page (1|2) of 3")
def _(ctx):
    import tifffile

    ctx.file = ctx.tmp / "contig.tif"
    rng = np.random.default_rng(1)
    tifffile.imwrite(ctx.file, (rng.random((3, *SHAPE)) * 4000).astype(np.uint16),
                     photometric="minisblack")  # page data first, page directories last
    data = ctx.file.read_bytes()
    ctx.file.write_bytes(data[: int(len(data) * 0.8)])
    open_stack(ctx.file)


@case("tiff_truncated_in_track", ValueError, r"truncated: page 2 of 3")
def _(ctx):
    ctx.file = _tiff_stack(ctx)
    data = ctx.file.read_bytes()
    ctx.file.write_bytes(data[:-5000])
    track(ctx.file, subset=31, step=32)


@case("folder_mixed_sizes", ValueError, r"img_2\.tif is 96 x 128 pixels, but img_0\.tif")
def _(ctx):
    import tifffile

    folder = ctx.tmp / "frames"
    folder.mkdir()
    ref, dfm = ctx.pair
    for k, img in enumerate([ref, dfm, dfm[:96]]):
        tifffile.imwrite(folder / f"img_{k}.tif", img)
    ctx.file = folder / "img_2.tif"
    track(folder, subset=31, step=32)


@case("folder_mixed_sizes_read", ValueError, r"img_1\.tif is 96 x 128 pixels")
def _(ctx):
    import tifffile

    folder = ctx.tmp / "frames"
    folder.mkdir()
    for k, shape in enumerate([SHAPE, (96, 128)]):
        tifffile.imwrite(folder / f"img_{k}.tif", np.zeros(shape, np.uint16))
    ctx.file = folder / "img_1.tif"
    open_stack(folder)[1]


@case("folder_unreadable_image", ValueError, r"cannot read image")
def _(ctx):
    import tifffile

    folder = ctx.tmp / "frames"
    folder.mkdir()
    tifffile.imwrite(folder / "img_0.tif", np.zeros(SHAPE, np.uint16))
    ctx.file = folder / "img_1.png"
    ctx.file.write_text("not an image")
    open_stack(folder)[1]


# =================================================================== the test
@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_input_gets_a_clear_error(ctx, name):
    fn, error, pattern = CASES[name]
    with pytest.raises(error) as info:
        fn(ctx)
    msg = str(info.value)
    assert re.search(pattern, msg), f"{name}: {type(info.value).__name__}: {msg}"
    if ctx.file is not None:
        assert ctx.file.name in msg, f"{name}: the message does not name the file: {msg}"


# =================================================================== what stays fine
def test_search_larger_than_the_image_is_clipped(pair):
    res = correlate(*pair, subset=31, step=8, search=10_000, search_max=10**9)
    assert res.params.search == max(SHAPE) and res.params.search_max == max(SHAPE)
    err = np.hypot(res.u[res.valid] - 0.4, res.v[res.valid] + 0.2)
    assert res.n_valid == len(res) and err.max() < 0.02


def test_full_lattice_strain_window_still_works(result):
    s = compute_strain(result, window=23)  # 2 * 12 - 1: every node in every fit
    assert np.allclose(s.exx[s.valid], 0, atol=2e-3) and s.valid.all()


def test_good_file_still_loads(ctx):
    back = load_result(ctx.good)
    assert np.array_equal(back.u, ctx.res.u) and np.array_equal(back.roi, ctx.res.roi)
