"""``napari-aldic advise``: the smallest subset that meets a displacement-noise
target, from the reference image alone; ``napari-aldic noise-floor``: the
displacement and strain noise measured on a static pair."""

from __future__ import annotations

import json
import unicodedata
from pathlib import Path

from ..engine import advise_subset, noise_floor
from ..engine.io import read_image
from ..i18n import tr
from .console import CLIError
from .masks import read_mask
from .settings import settings_from_args


def _rjust(text: str, width: int) -> str:
    """``text`` right-aligned in ``width`` terminal columns: CJK characters take
    two columns, so padding by character count would misalign the headings."""
    cols = sum(2 if unicodedata.east_asian_width(c) in "WF" else 1 for c in text)
    return " " * max(width - cols, 0) + text


def _image(path: Path):
    if not path.exists():
        raise CLIError(tr("no such file: {path}").format(path=path))
    return read_image(path)


def advise_command(args) -> None:
    """Print the table subset -> predicted noise and the recommendation."""
    img = _image(args.image)
    roi = read_mask(args.roi) if args.roi is not None else None
    subsets = args.subsets or None
    adv = advise_subset(img, roi, args.target_noise, step=args.step, subsets=subsets,
                        noise=args.noise, coverage=args.coverage)
    print(tr("image noise {noise:.2f} grey levels ({how}); target {target:g} px "
             "(nodes to meet it: {percent:.0f} %)").format(
        noise=adv.noise, how=tr("given") if args.noise is not None else tr("estimated"),
        target=adv.target, percent=100 * adv.coverage))
    heads = (tr("subset"), tr("median (px)"), tr("90th pct (px)"), tr("meeting target"))
    print(" ".join(_rjust(h, w) for h, w in zip(heads, (7, 13, 13, 15))))
    for r in adv.rows:
        print(f"{r['subset']:>7d} {r['median_std_px']:>13.4f} {r['p90_std_px']:>13.4f} "
              f"{100 * r['fraction']:>14.1f}%")
    if adv.recommended is None:
        print(tr("no tried subset reaches {target:g} px: use a larger subset, a better "
                 "speckle pattern or less image noise").format(target=adv.target))
    else:
        print(tr("recommended subset: {subset} px").format(subset=adv.recommended))
    if args.json is not None:
        args.json.write_text(json.dumps(adv.__dict__, indent=2), encoding="utf-8")
        print("  -> " + str(args.json.resolve()))


def noise_floor_command(args) -> None:
    """Print (and optionally save) the noise floor of a static pair."""
    ref, static = _image(args.reference), _image(args.static)
    roi = read_mask(args.roi) if args.roi is not None else None
    params = settings_from_args(args, args.params).params
    nf = noise_floor(ref, static, roi, params=params, strain_window=args.window)
    print(tr("noise floor of the static pair ({valid} valid nodes; subset {subset} px, "
             "step {step} px, {method}; strain window {window} nodes)").format(
        valid=nf["n_valid"], subset=nf["subset"], step=nf["step"], method=nf["method"],
        window=nf["strain_window"]))
    print(tr("  displacement std: u {u:.4f} px, v {v:.4f} px (drift {du:+.4f}, {dv:+.4f} px "
             "removed)").format(u=nf["u_std_px"], v=nf["v_std_px"], du=nf["drift_px"][0],
                                dv=nf["drift_px"][1]))
    print(tr("  strain std: exx {exx:.2e}, eyy {eyy:.2e}, exy {exy:.2e}").format(
        exx=nf["exx_std"], eyy=nf["eyy_std"], exy=nf["exy_std"]))
    if args.output is not None:
        args.output.write_text(json.dumps(nf, indent=2), encoding="utf-8")
        print("  -> " + str(args.output.resolve()))
