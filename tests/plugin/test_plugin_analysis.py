"""What the Run button computes (napari-free): frame ranges, brush refinement, strain."""

from __future__ import annotations

import numpy as np
import pytest

from napari_aldic._analysis import StrainSettings, run_analysis
from napari_aldic.engine import DICParams


def test_frame_range_and_stride_map_to_stack_indices(speckle_stack):
    stack = speckle_stack(5, (128, 128))
    reports = []
    a = run_analysis(stack, None, DICParams(subset=21, step=16), start=1, stop=4, stride=2,
                     progress=reports.append)
    assert a.frames == [1, 3] and a.n_frames == 5 and not a.cancelled
    assert a.results[1].meta["frame"] == 3
    # stack indices in the events and their text (no frame number rewritten in a message)
    done = [e for e in reports if e.stage == "frame_done"]
    assert [(e.frame, e.reference) for e in done] == [(3, 1)]
    assert str(done[0]).startswith("frame 3 done")
    assert {e.frame for e in reports} == {3} and reports[-1].stage == "strain"
    # frame 3 against frame 1: the translation difference of the synthetic stack
    r = a.results[1]
    assert np.allclose(np.nanmedian(r.u[r.valid]), 0.6, atol=0.02)
    assert np.allclose(np.nanmedian(r.v[r.valid]), -0.4, atol=0.02)
    with pytest.raises(ValueError, match="not valid"):
        run_analysis(stack, None, DICParams(), start=3, stop=3)


def test_brush_region_refines_the_mesh_and_strain_matches(plugin_field, speckle_stack):
    stack = speckle_stack()
    brush = np.zeros(stack.shape[1:], bool)
    brush[60:100, 60:100] = True
    params = DICParams(subset=21, step=16, method="aldic")
    plain = run_analysis(stack, None, params, strain=StrainSettings(window=3))
    refined = run_analysis(stack, None, params, brush=brush, strain=StrainSettings(window=3))
    assert len(refined.results[2]) > len(plain.results[2])  # extra quadtree nodes
    assert refined.results[2].meta["refine"]["brush"]
    r, s = refined.results[2], refined.strains[2]
    ut, vt = plugin_field(2).displacement(r.x, r.y)
    assert np.abs(r.u - ut)[r.valid].max() < 0.05
    G = np.asarray(plugin_field(2).G)
    assert np.nanmedian(s.exx[s.valid]) == pytest.approx(G[0, 0] + 0.5 * (G[0, 0] ** 2
                                                                         + G[1, 0] ** 2),
                                                         abs=1e-3)
    assert np.all(refined.results[0].u == 0)  # the reference frame is a zero field
    with pytest.raises(ValueError, match="accumulative"):
        run_analysis(stack, None, params, brush=brush, reference="incremental")
