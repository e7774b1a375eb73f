"""``napari-aldic demo``: a synthetic speckle pair, its analysis, the error
against the exact truth, and the files to analyse it again."""

from __future__ import annotations

import json
import time

import numpy as np

from ..engine import correlate
from ..engine.synthetic import make_case
from ..engine.viz import plot_displacement
from ..i18n import tr
from .console import PROG, CLIError, counts_line, kernel_groups, precompile, progress_bar


def demo_command(args) -> None:
    """``napari-aldic demo``: synthetic pair, analysis, error report, files."""
    out = args.out.expanduser().resolve()
    precompile(kernel_groups(args.method, "synthetic"))  # a first run: in parallel processes
    case = make_case(args.field, (args.size, args.size), noise=args.noise, seed=args.seed)
    print(tr("{prog} demo: {size} x {size} synthetic speckle pair, 8-bit, "
             "noise {noise:g} grey levels").format(
                 prog=PROG, size=args.size, noise=args.noise))
    print("  " + tr("field: {description}").format(description=case.description))
    print("  " + tr("warming up the kernels (loaded from Numba's cache; a kernel not "
                    "compiled yet compiles now) ..."), flush=True)
    warm = _warm_up(args)
    print("  " + tr("warm-up: {warm:.1f} s (Numba compiles the kernels on a first "
                    "run, later runs load them from its cache; not part of the "
                    "analysis time)").format(warm=warm))
    res = correlate(case.reference, case.deformed, roi=case.roi, subset=args.subset,
                    step=args.step, method=args.method,
                    progress=progress_bar("  " + tr("correlate")))
    print("  " + tr("analysis:") + " " + counts_line(res))
    stats = _errors(res, case)
    print("  " + tr("error against the exact truth over the {n_valid} valid nodes:").format(
                        n_valid=res.n_valid))
    print("    " + tr("u: RMSE {rmse_u:.4f} px, max {max_u:.4f} px").format(
                          rmse_u=stats['rmse_u'], max_u=stats['max_u']))
    print("    " + tr("v: RMSE {rmse_v:.4f} px, max {max_v:.4f} px").format(
                          rmse_v=stats['rmse_v'], max_v=stats['max_v']))
    res.meta["demo"] = {"field": args.field, "description": case.description,
                        "size": args.size, "noise": args.noise, "seed": args.seed, **stats}
    written, roi_opt = _write_files(out, case, res, args.field)
    print("  " + tr("wrote {join} to").format(join=', '.join(written)))
    print(f"  {out}")
    print("  " + tr("analyse them again with: {prog} run {reference} {deformed}{roi_opt} "
                    "--params {params} -o result.npz").format(
                        prog=PROG, reference=out / 'reference.tif', deformed=out / 'deformed.tif',
                        roi_opt=roi_opt, params=out / 'params.json'))


def _warm_up(args) -> float:
    """Correlate a small pair of the same kind with the same settings, so that
    compiling (or loading) the kernels is timed apart from the analysis; seconds."""
    size = max(4 * args.subset, 128)
    small = make_case(args.field, (size, size), noise=args.noise, seed=args.seed + 1)
    t0 = time.perf_counter()
    correlate(small.reference, small.deformed, roi=small.roi, subset=args.subset,
              step=args.step, method=args.method)
    return time.perf_counter() - t0


def _errors(res, case) -> dict[str, float]:
    """RMSE and largest error of u and v over the valid nodes, in pixels."""
    ut, vt = case.field.displacement(res.x, res.y)
    sel = res.valid
    if not sel.any():
        raise CLIError(tr("no node converged; nothing to compare with the truth"))
    eu, ev = res.u[sel] - ut[sel], res.v[sel] - vt[sel]
    return {"rmse_u": float(np.sqrt(np.mean(eu**2))), "max_u": float(np.abs(eu).max()),
            "rmse_v": float(np.sqrt(np.mean(ev**2))), "max_v": float(np.abs(ev).max())}


def _write_files(out, case, res, field: str) -> tuple[list[str], str]:
    """Images, ROI, result, parameters and figure into ``out``: (names written,
    the ``--roi`` option of the command that analyses them again)."""
    import tifffile

    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, img in (("reference.tif", case.reference), ("deformed.tif", case.deformed)):
        tifffile.imwrite(out / name, img, photometric="minisblack")
        written.append(name)
    roi_opt = ""
    if case.roi is not None:
        tifffile.imwrite(out / "roi.tif", case.roi.astype(np.uint8) * 255,
                         photometric="minisblack")
        written.append("roi.tif")
        roi_opt = f" --roi {out / 'roi.tif'}"
    res.save(out / "result.npz")
    (out / "params.json").write_text(json.dumps(res.params.to_dict(), indent=2) + "\n")
    plot_displacement(res, out / "displacement.png", truth=case.field, image=case.reference,
                      title=f"demo '{field}': {case.description}")
    written += ["result.npz", "params.json", "displacement.png"]
    return written, roi_opt
