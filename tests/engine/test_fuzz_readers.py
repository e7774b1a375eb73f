"""Issue 23: a fuzz test of the readers with generated hostile inputs.

Every reader of a file a user hands over (result ``.npz``, parameter JSON, run
manifest, TIFF stack, load CSV, project file) is given files made from a good one
by a seeded generator: truncated, bytes flipped or overwritten, garbage inserted,
JSON values swapped for other types, deep nesting, huge numbers. Each must either
read the file (and then what it returns is sound) or raise ``ValueError`` (or
``FileNotFoundError``) whose message names the file, quickly: never another error
type, never a hang. (hypothesis is not installed in the venv: a seeded generator
keeps the cases reproducible.)
"""

from __future__ import annotations

import json
import random
import time

import numpy as np
import pytest

from napari_aldic.engine import correlate, load_result, load_run, synthetic as S, track
from napari_aldic.engine.core.npzfile import check_invariants
from napari_aldic.engine.io import open_stack, read_settings
from napari_aldic.engine.probes import read_load_csv

N_CASES = 40  # per reader
SEED = 2323


def _mutations(good: bytes, rng: random.Random):
    """Hostile variants of the bytes of a good file."""
    n = len(good)
    for _ in range(N_CASES):
        kind = rng.randrange(6)
        data = bytearray(good)
        if kind == 0:  # truncated
            data = data[:rng.randrange(n)]
        elif kind == 1:  # bytes flipped
            for _ in range(rng.randint(1, 8)):
                data[rng.randrange(n)] ^= 1 << rng.randrange(8)
        elif kind == 2:  # a block overwritten with noise
            at = rng.randrange(n)
            data[at:at + 16] = bytes(rng.randrange(256) for _ in range(16))
        elif kind == 3:  # garbage inserted
            at = rng.randrange(n)
            data[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 64)))
        elif kind == 4:  # the start of the file destroyed (headers)
            data[:32] = bytes(rng.randrange(256) for _ in range(32))
        else:  # nothing like the format
            data = bytearray(rng.randbytes(rng.randint(0, 256)))
        yield bytes(data)


def _json_mutations(doc, rng: random.Random):
    """Hostile variants of a JSON document: values of the wrong type, hostile text."""
    hostile = [None, 5, -1, 1e308, "abc", [], {}, [1, 2, 3], True, "9" * 5000,
               {"a": [[[[]]]]}, [[1, "x"]], float("nan")]
    keys = list(doc) if isinstance(doc, dict) else []
    for i in range(N_CASES):
        if i % 8 == 0:
            yield ("[" * 100_000 + "]" * 100_000).encode()
        elif i % 8 == 1:
            yield ('{"x": ' + "1" * 6000 + "}").encode()
        elif i % 8 == 2:
            yield json.dumps(rng.choice(hostile)).encode()
        else:
            bad = json.loads(json.dumps(doc))
            for _ in range(rng.randint(1, 3)):
                target = bad
                key = rng.choice(keys)
                while isinstance(target.get(key), dict) and target[key] and rng.random() < 0.5:
                    target = target[key]
                    key = rng.choice(list(target))
                target[key] = rng.choice(hostile)
            yield json.dumps(bad).encode()


def _check(read, path, payloads, sound=lambda value: None):
    for i, payload in enumerate(payloads):
        path.write_bytes(payload)
        t0 = time.perf_counter()
        try:
            value = read(path)
        except (ValueError, FileNotFoundError) as exc:
            assert str(path) in str(exc) or path.name in str(exc), (i, str(exc))
        except Exception as exc:  # the obscure errors this test is here to find
            raise AssertionError(f"case {i}: {type(exc).__name__}: {exc}") from exc
        else:
            sound(value)
        assert time.perf_counter() - t0 < 20, f"case {i} took too long"


@pytest.fixture(scope="module")
def pair():
    return S.speckle_pair((96, 96), S.Translation(0.4, -0.2), seed=1)


def test_fuzz_result_files(pair, tmp_path):
    good = correlate(*pair, subset=21, step=16).save(tmp_path / "good.npz").read_bytes()

    def sound(res):
        assert check_invariants(res.__dict__) is None

    at = good.index(b"PK\x01\x02") + 6  # "version needed to extract" of the first member
    newer = good[:at] + b"\xe0\x00" + good[at + 2:]  # zipfile: NotImplementedError
    payloads = [newer, *_mutations(good, random.Random(SEED))]
    _check(load_result, tmp_path / "bad.npz", payloads, sound)


def test_fuzz_parameter_files(tmp_path):
    doc = {"format": "napari-aldic-settings", "format_version": 1,
           "params": {"subset": 21, "step": 8, "method": "aldic", "smooth": 5},
           "units": {"pixel_size": 1.5, "unit": "µm"}}
    good = json.dumps(doc).encode()
    rng = random.Random(SEED + 1)
    payloads = [*_mutations(good, rng), *_json_mutations(doc, rng)]
    _check(read_settings, tmp_path / "p.json", payloads)


def test_fuzz_run_manifests(pair, tmp_path):
    folder = tmp_path / "run"
    track(np.stack([pair[0], pair[1], pair[1]]), subset=21, step=24, out_dir=folder)
    manifest = folder / "sequence.json"
    doc = json.loads(manifest.read_text())
    rng = random.Random(SEED + 2)
    payloads = [*_mutations(manifest.read_bytes(), rng), *_json_mutations(doc, rng)]

    def read(path):
        seq = load_run(folder)
        return [seq[k] for k in range(len(seq.frames)) if seq.frames.present[k]]

    _check(read, manifest, payloads)


def test_fuzz_tiff_stacks(pair, tmp_path):
    import tifffile

    tifffile.imwrite(tmp_path / "good.tif", np.stack([pair[0], pair[1], pair[1]]),
                     photometric="minisblack")
    good = (tmp_path / "good.tif").read_bytes()

    def read(path):
        src = open_stack(path)
        try:
            return [src[k] for k in range(len(src))]
        finally:
            src.close()

    _check(read, tmp_path / "bad.tif", _mutations(good, random.Random(SEED + 3)))


def test_fuzz_load_csvs(tmp_path):
    rows = "\n".join(f"{0.5 * k},{1.5 * k},{k}" for k in range(30))
    good = f"# machine X\ntime (s),load (kN),frame\n{rows}\n".encode()
    rng = random.Random(SEED + 4)
    texts = [b"time;load\n1;abc\n2;3\n", "time,load\n".encode("utf-16") + b"\x00",
             b"\xff\xfe\x00\x00garbage", good.replace(b"1.5", b"inf"),
             good + b"time (s),load (kN),frame\n" + rows.encode()]

    def sound(rec):
        assert np.all(np.isfinite(rec.load_N)) and len(rec) >= 2

    _check(read_load_csv, tmp_path / "load.csv", [*_mutations(good, rng), *texts], sound)


def test_fuzz_project_files(tmp_path):
    from napari_aldic._qt.project import encode_array, read_project, write_project

    img = tmp_path / "img.tif"
    img.write_bytes(b"II*\x00" + bytes(100))
    doc = {"image": {"name": "img", "path": str(img), "sample": None, "shape": [10, 10],
                     "files": None, "scale": [1.0, 1.0], "translate": [0.0, 0.0]},
           "layers": [{"role": "roi_add", "type": "shapes", "name": "roi",
                       "scale": [1.0, 1.0], "translate": [0.0, 0.0],
                       "data": [[[0, 0], [0, 5], [5, 5]]], "shape_type": ["polygon"],
                       "edge_width": [1.0]},
                      {"role": "seeds", "type": "points", "name": "seeds",
                       "scale": [1.0, 1.0], "translate": [0.0, 0.0], "data": [[1, 2]]},
                      {"role": "brush", "type": "labels", "name": "brush",
                       "scale": [1.0, 1.0], "translate": [0.0, 0.0],
                       "data": encode_array(np.zeros((10, 10), np.uint8))}],
           "settings": {}}
    path = write_project(tmp_path / "good.json", doc)
    good = path.read_bytes()
    full = json.loads(good)
    rng = random.Random(SEED + 5)
    payloads = [*_mutations(good, rng), *_json_mutations(full, rng)]
    for i in range(N_CASES):  # one stored layer made hostile
        bad = json.loads(good)
        layer = rng.choice(bad["layers"])
        key = rng.choice([k for k in layer if k not in ("role", "type")])
        layer[key] = rng.choice([None, 5, "x", [1, 2, 3, 4, 5], [["a", "b"]], {},
                                 {"dtype": "<u1", "shape": [1 << 20, 1 << 20],
                                  "zlib_base64": ""}])
        if i % 10 == 0:
            del layer[key]
        payloads.append(json.dumps(bad).encode())
    _check(read_project, tmp_path / "p.json", payloads)
