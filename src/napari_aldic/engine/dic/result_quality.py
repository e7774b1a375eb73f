"""The quality fields a result carries (``sssig``, ``mig``, ``u_std``,
``v_std``: :mod:`.quality`, and for AL-DIC :mod:`.uncertainty_aldic`), and
the parts of them that depend on the reference alone as jobs that
``correlate`` starts ahead on a background thread (``Images.prefetch``,
read back through ``Images.memo``): the speckle quality of the nodes, the
sums of AL-DIC's noise probes and the local maps the propagation makes of
them (:func:`~.uncertainty_aldic.probe_maps`)."""

from __future__ import annotations

import numpy as np

from ..core.files import array_digest
from .quality import SHAPE_TERMS, node_uncertainty, speckle_quality
from .threads import beside
from .uncertainty_aldic import aldic_gain, noise_projector, probe_maps

__all__ = ["result_quality", "speckle_job", "probe_job", "probes_key", "maps_key", "maps_job"]


def result_quality(f, gradients, order: int, roi, x, y, subset: int, *, zncc, u, v, grad,
                   shape_function: str = "affine", jacobian=None, aldic=None,
                   memo=None) -> dict:
    """The quality fields ``correlate`` stores with a result: ``sssig``,
    ``mig`` and the standard uncertainty ``u_std``, ``v_std`` (px) of the
    subset displacements ``u``, ``v`` (pass ``zncc=None`` for the fields of
    the reference alone: no uncertainty). ``jacobian``: ``(jx, jy, sigma)``,
    the gradients of the steepest-descent images when they are smoothed ones
    and the smoothing (px) they were made with.
    ``aldic``: an :class:`~.uncertainty_aldic.ADMMLinearisation` of the run
    when ``u``, ``v`` are AL-DIC's local estimates: ``u_std``, ``v_std`` then
    describe the smoothed global field (:func:`~.uncertainty_aldic.aldic_gain`).
    ``memo``: :meth:`~.images.Images.memo` of the pair, which keeps the speckle
    quality (the reference's alone) for the next pair with this reference."""
    xi = np.rint(np.asarray(x, float)).astype(np.int64)
    yi = np.rint(np.asarray(y, float)).astype(np.int64)
    sd_images = jacobian if jacobian is not None else gradients
    key, quality = speckle_job(f, gradients, order, roi, xi, yi, subset, shape_function,
                               None if zncc is None else jacobian)
    q = quality() if memo is None else memo(key, quality)
    out = {"sssig": q.sssig, "mig": q.mig, "u_std": None, "v_std": None}
    if zncc is not None:
        gain = None
        if aldic is not None:
            base, project = _projector(sd_images, roi, xi, yi, subset, shape_function)
            if memo is not None:  # the probes may have been summed ahead (probe_job)
                plain = project

                def project(rng, count=1):
                    return memo((*base, str(rng.bit_generator.state), count),
                                lambda: plain(rng, count))
                project.apply = plain.apply
            pkey = probes_key(base, aldic.seed, aldic.probes)

            def maps():
                return probe_maps(q, project(np.random.default_rng(aldic.seed), aldic.probes),
                                  aldic.mu)
            mkey = maps_key(key, pkey, aldic.mu)

            def gain():
                return aldic_gain(q, project, aldic, maps() if memo is None else memo(mkey, maps))
        if gain is None:
            s = node_uncertainty(q, zncc, u, v, grad, order)
        else:
            # the probes leave a core idle a third of their time: the Local model fills it
            g, s = beside(gain, lambda: node_uncertainty(q, zncc, u, v, grad, order))
            s = s * g
        out["u_std"], out["v_std"] = s[:, 0], s[:, 1]
    return out


def speckle_job(f, gradients, order: int, roi, x, y, subset: int, shape_function="affine",
                jacobian=None) -> tuple:
    """``(key, compute)``: the speckle quality of :func:`result_quality` (the
    reference's alone, :func:`speckle_quality`) as a job, and the key under
    which ``Images.memo`` keeps it (``Images.prefetch`` starts it ahead)."""
    xi = np.rint(np.asarray(x, float)).astype(np.int64)
    yi = np.rint(np.asarray(y, float)).astype(np.int64)

    def compute():
        return speckle_quality(f, xi, yi, subset, roi, shape_function=shape_function,
                               order=order, gradients=gradients, jacobian=jacobian)
    key = ("speckle", array_digest(np.asarray(roi)) if roi is not None else None,
           array_digest(xi), array_digest(yi), subset, shape_function, order,
           None if jacobian is None else float(jacobian[2]))
    return key, compute


def _projector(sd_images, roi, xi, yi, subset: int, shape_function: str) -> tuple:
    """The noise projector of the nodes (:func:`~.uncertainty_aldic.noise_projector`)
    and the start of the memo key of its sums."""
    base = ("probes", array_digest(np.asarray(roi)) if roi is not None else None,
            array_digest(xi), array_digest(yi), subset, shape_function,
            float(sd_images[2]) if len(sd_images) > 2 else None)
    return base, noise_projector(*sd_images[:2], xi, yi, subset, roi, SHAPE_TERMS[shape_function])


def probe_job(gradients, roi, x, y, subset: int, shape_function="affine", jacobian=None,
              seed: int = 0, count: int = 16) -> tuple:
    """``(key, compute)``: the sums of ``count`` noise probes drawn from
    ``seed`` that AL-DIC's ``u_std`` propagation needs
    (:func:`~.uncertainty_aldic.aldic_gain`, the reference's alone), as a
    job for ``Images.prefetch`` and the key :func:`result_quality` asks for."""
    xi = np.rint(np.asarray(x, float)).astype(np.int64)
    yi = np.rint(np.asarray(y, float)).astype(np.int64)
    base, project = _projector(jacobian if jacobian is not None else gradients, roi, xi, yi,
                               subset, shape_function)
    rng = np.random.default_rng(seed)
    return probes_key(base, seed, count), lambda: project(rng, count)


def probes_key(base: tuple, seed: int, count: int) -> tuple:
    """The memo key of ``count`` probes' sums drawn from ``seed`` (``base``:
    of the nodes and steepest-descent images, :func:`_projector`)."""
    return (*base, str(np.random.default_rng(seed).bit_generator.state), count)


def maps_key(speckle: tuple, probes: tuple, mu: float) -> tuple:
    """The memo key of :func:`~.uncertainty_aldic.probe_maps` from the speckle
    quality and probe sums of these keys (:func:`speckle_job`,
    :func:`probe_job`) and the penalty ``mu``."""
    return ("probe maps", speckle, probes, float(mu))


def maps_job(speckle, probes, mu: float) -> tuple:
    """``(key, compute)``: :func:`~.uncertainty_aldic.probe_maps` as a job for
    ``Images.prefetch``, from the speckle quality and the probe sums as
    ``(key, future)`` pairs (the prefetched jobs of :func:`speckle_job` and
    :func:`probe_job`, taken before ``memo`` can claim them)."""
    return (maps_key(speckle[0], probes[0], mu),
            lambda: probe_maps(speckle[1].result(), probes[1].result(), mu))
