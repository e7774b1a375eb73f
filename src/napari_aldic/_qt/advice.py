"""Subset advice in the widget: the "Advise subset" button of the correlation
panel runs :func:`~napari_aldic.engine.advise_subset` on the reference frame
and ROI in a worker thread and writes the table and the recommendation to the
log (the subset is set only when the user accepts it by clicking again)."""

from __future__ import annotations

import numpy as np

from ..engine import advise_subset
from ..i18n import tr

__all__ = ["start_advice", "advice_lines"]


def advice_lines(adv) -> list[str]:
    """The advice as log lines (translated)."""
    lines = [tr("subset advice: image noise {noise:.2f} grey levels, target {target:g} px "
                "(nodes to meet it: {percent:.0f} %)").format(
        noise=adv.noise, target=adv.target, percent=100 * adv.coverage)]
    for r in adv.rows:
        lines.append(tr("  subset {subset} px: median {median:.4f} px, nodes meeting the "
                        "target: {fraction:.0f} %").format(
            subset=r["subset"], median=r["median_std_px"], fraction=100 * r["fraction"]))
    if adv.recommended is None:
        lines.append(tr("no tried subset reaches the target: a better speckle pattern, less "
                        "image noise or a larger target is needed"))
    else:
        lines.append(tr("recommended subset: {subset} px").format(subset=adv.recommended))
    return lines


def start_advice(widget) -> None:
    """Run the advice for ``widget`` (a DICWidget) off the GUI thread."""
    from napari.qt.threading import create_worker
    from superqt.utils import FunctionWorker

    log, c, inputs = widget.run_panel.write_log, widget.correlation, widget.inputs
    data = inputs.stack_data
    if data is None:
        log(tr("subset advice: choose an image first"))
        return
    start = int(c.start.value)
    shape = tuple(data.shape[-2:])
    try:
        roi, _ = inputs.roi(shape, start)
        ref = np.asarray(data[start] if len(data.shape) == 3 else data)
    except Exception as exc:  # a broken ROI layer must not break the widget
        log(tr("subset advice failed: {exc}").format(exc=exc))
        return
    log(tr("subset advice: computing on frame {frame} ...").format(frame=start))
    worker = create_worker(advise_subset, ref, roi, float(c.target_noise.value),
                           _worker_class=FunctionWorker, _ignore_errors=True)
    worker.returned.connect(lambda adv: _show(widget, adv))
    worker.errored.connect(lambda exc: log(tr("subset advice failed: {exc}").format(exc=exc)))
    c.advise.enabled = False
    worker.finished.connect(lambda: setattr(c.advise, "enabled", True))
    widget._advice_worker = worker  # keep it alive until it finishes
    worker.start()


def _show(widget, adv) -> None:
    for line in advice_lines(adv):
        widget.run_panel.write_log(line)
    c = widget.correlation
    if adv.recommended is not None:
        c.advise.tooltip = tr("Last advice: subset {subset} px for {target:g} px").format(
            subset=adv.recommended, target=adv.target)
