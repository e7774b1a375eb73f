"""Exact-truth 3-D speckle volumes for tests, benchmarks and the docs.

A pattern is a set of Gaussian blobs. The deformed volume of an affine
motion ``x = A X + t`` (translation, strain, rotation) evaluates the same
blobs at the inverse-mapped point of every voxel, so it is exact: the truth
is ``u(X) = (A - I) X + t`` everywhere, with nothing interpolated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kernels.speckle3d import render_blobs

__all__ = ["VolumeMotion", "speckle_volume_pair", "VOLUME_CASES", "volume_case"]


@dataclass(frozen=True)
class VolumeMotion:
    """An affine motion ``x = A X + t`` in voxels, (x, y, z) order.

    ``A`` (3 x 3) is ``I + grad u``; :meth:`displacement` gives the exact
    Lagrangian displacement at reference points.
    """

    A: np.ndarray
    t: np.ndarray

    @classmethod
    def make(cls, *, shift=(0.0, 0.0, 0.0), strain=(0.0, 0.0, 0.0), angle_deg: float = 0.0,
             axis: str = "z", centre=(0.0, 0.0, 0.0)) -> VolumeMotion:
        """Normal strains ``(exx, eyy, ezz)``, then a rotation of ``angle_deg``
        about ``axis`` through ``centre``, then ``shift`` (voxels)."""
        S = np.diag(1.0 + np.asarray(strain, float))
        a = np.deg2rad(angle_deg)
        c, s = np.cos(a), np.sin(a)
        i, j = {"z": (0, 1), "y": (2, 0), "x": (1, 2)}[axis]
        R = np.eye(3)
        R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
        A = R @ S
        c0 = np.asarray(centre, float)
        t = c0 - A @ c0 + np.asarray(shift, float)
        return cls(A=A, t=t)

    def displacement(self, x, y, z) -> np.ndarray:
        """``(n, 3)`` displacement (u, v, w) at reference points."""
        X = np.stack([np.ravel(x), np.ravel(y), np.ravel(z)], 1).astype(float)
        return X @ (self.A - np.eye(3)).T + self.t


def _render(shape, centres, sigma, amp, motion: VolumeMotion, lo, hi) -> np.ndarray:
    out = np.zeros(shape)
    render_blobs(out, centres, sigma, amp, np.linalg.inv(motion.A), motion.t, 4.0)
    # blobs overlap: squash the sum into [lo, hi] smoothly (same map both volumes)
    return (lo + (hi - lo) * (1.0 - np.exp(-out))).astype(np.float32)


def speckle_volume_pair(shape=(128, 128, 128), motion: VolumeMotion | None = None, *,
                        radius: float = 1.6, density: float = 0.008, noise: float = 0.0,
                        seed: int = 0, lo: float = 20.0, hi: float = 220.0):
    """A reference and a deformed speckle volume, (z, y, x) float32 grey levels.

    Parameters
    ----------
    shape : (nz, ny, nx)
    motion : VolumeMotion, default no motion
    radius : blob sigma (voxels); density: blobs per voxel
    noise : Gaussian noise standard deviation in grey levels (both volumes,
        independent draws)
    seed : random seed of the pattern and the noise

    Returns
    -------
    ref, dfm : (nz, ny, nx) float32
    """
    motion = motion or VolumeMotion.make()
    rng = np.random.default_rng(seed)
    nz, ny, nx = shape
    margin = 12.0  # blobs outside the volume move in through the edges
    n = int(density * (nx + 2 * margin) * (ny + 2 * margin) * (nz + 2 * margin))
    lo3 = np.array([-margin] * 3)
    hi3 = np.array([nx, ny, nz]) + margin
    centres = rng.uniform(lo3, hi3, size=(n, 3))
    sigma = radius * rng.uniform(0.7, 1.3, n)
    amp = rng.uniform(0.5, 1.5, n)
    ref = _render(shape, centres, sigma, amp, VolumeMotion.make(), lo, hi)
    dfm = _render(shape, centres, sigma, amp, motion, lo, hi)
    if noise > 0:
        ref = ref + rng.normal(0.0, noise, shape).astype(np.float32)
        dfm = dfm + rng.normal(0.0, noise, shape).astype(np.float32)
    return ref, dfm


#: the benchmark cases of the issue (centre of rotation at the volume centre)
VOLUME_CASES = ("translation", "strain1", "rotation5", "strain2_noise")


def volume_case(name: str, shape=(128, 128, 128), seed: int = 0):
    """``(ref, dfm, motion)`` of a named case of :data:`VOLUME_CASES`."""
    centre = tuple((s - 1) / 2 for s in shape[::-1])
    motions = {
        "translation": (VolumeMotion.make(shift=(2.3, -1.6, 0.7)), 0.0),
        "strain1": (VolumeMotion.make(strain=(0.01, 0.0, 0.0), centre=centre), 0.0),
        "rotation5": (VolumeMotion.make(angle_deg=5.0, centre=centre), 0.0),
        "strain2_noise": (VolumeMotion.make(strain=(0.02, -0.005, 0.0), centre=centre), 2.0),
    }
    if name not in motions:
        raise ValueError(f"unknown volume case {name!r}; choose one of {VOLUME_CASES}")
    motion, noise = motions[name]
    ref, dfm = speckle_volume_pair(shape, motion, noise=noise, seed=seed)
    return ref, dfm, motion
