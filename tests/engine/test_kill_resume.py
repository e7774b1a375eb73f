"""Issue 23: a run killed (SIGKILL) at any moment leaves a folder that resumes to the
uninterrupted result.

A child process runs ``track`` into a run folder and kills itself at its N-th write
(every write of the field store, every rename and hard link counts: the store's
``zarr.json`` appearing, a frame's slices, a result file's rename, the lock). The
folder it leaves is then resumed here and compared with an uninterrupted run: the
same frames to 1e-3 px (the resumed frames start from their own FFT guess).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from napari_aldic.engine import load_run, synthetic as S, track

pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="no SIGKILL here")

CHILD = r"""
import os, signal, sys
import zarr.storage

N, count = int(sys.argv[3]), [0]

def tick():
    count[0] += 1
    if count[0] == N:
        os.kill(os.getpid(), signal.SIGKILL)

store_set = zarr.storage.LocalStore.set

async def counted(self, key, value):
    tick()
    return await store_set(self, key, value)

zarr.storage.LocalStore.set = counted
for name in ("replace", "rename", "link"):
    def wrapped(*a, _f=getattr(os, name), **k):
        tick()
        return _f(*a, **k)
    setattr(os, name, wrapped)

from napari_aldic.engine import track
track(sys.argv[1], subset=21, step=16, out_dir=sys.argv[2])
print(count[0])
"""
#: where the child kills itself: its 3rd write (the field store being built under its
#: temporary name), then fractions of an uninterrupted run's writes (frames in progress)
MOMENTS = (3, 0.3, 0.6, 0.95)


@pytest.mark.slow
def test_a_killed_run_resumes_to_the_uninterrupted_result(tmp_path):
    import tifffile

    pat = S.make_pattern((96, 96), seed=3, margin=24)
    stack = np.stack([S.render(pat, (96, 96), None if k == 0 else
                               S.Translation(0.3 * k, -0.2 * k), n_quad=2, seed=k)
                      for k in range(4)]).astype(np.float32)
    tif = tmp_path / "stack.tif"
    tifffile.imwrite(tif, stack, photometric="minisblack")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [os.path.dirname(os.path.dirname(__import__("napari_aldic").__file__)),
         os.environ.get("PYTHONPATH", "")])}

    def child(out, n):
        return subprocess.run([sys.executable, "-c", CHILD, str(tif), str(out), str(n)],
                              env=env, capture_output=True, text=True, timeout=300)

    whole = child(tmp_path / "whole", 0)
    assert whole.returncode == 0, whole.stderr
    total = int(whole.stdout.split()[-1])
    ref = load_run(tmp_path / "whole")
    for m in MOMENTS:
        n = m if isinstance(m, int) else max(1, int(m * total))
        out = tmp_path / f"killed{n}"
        proc = child(out, n)
        assert proc.returncode == -signal.SIGKILL, (n, proc.stderr)
        seq = track(tif, subset=21, step=16, out_dir=out)  # resumes
        assert seq.complete, n
        again = load_run(out)
        for k in range(1, len(stack)):
            np.testing.assert_allclose(again[k].u, ref[k].u, atol=1e-3, err_msg=f"{n}, {k}")
            np.testing.assert_allclose(again[k].v, ref[k].v, atol=1e-3, err_msg=f"{n}, {k}")
        assert not [p for p in os.listdir(out) if p.endswith(".part")], n
