"""The volume fraction of a lattice voxel that lies inside a body, from the body's signed
distance: the default ``"fractional"`` filling of :mod:`holofit.dda.voxelize`.

Rule. For a voxel of side ``d`` centred where the body's signed distance is ``s`` (negative
inside), with unit normal ``n`` and Laplacian ``lap`` there, and ``t = (s + delta) / d``,

    f = (1 - beta) R(t) + beta P(n . u < -t),        u uniform in [-1/2, 1/2]^3,
    beta = clip((max_c |n_c| - A) / (1 - A), 0, 1)^2,     A = FACE_ALIGNMENT,
    delta = (lap / 2) d^2 ((1 - beta) / 28 + beta / 12),

where ``R(t) = 1 - smootherstep(t + 1/2)`` is a C2 ramp (1 for ``t <= -1/2``, 0 for
``t >= 1/2``) and ``P(n . u < -t)`` (:func:`box_cdf`) is the exact fraction of the voxel on the
inner side of the tangent plane (for a face parallel to a lattice plane, the linear
``1/2 - t`` on ``|t| <= 1/2``). A surface within about 25 degrees of a lattice plane blends
toward the exact plane fraction, which it reaches when parallel to the plane; steeper
surfaces get the ramp.

Why. A face parallel to the lattice planes is sampled at one offset from them all over, so its
voxelised volume is exact for every offset only with the exact plane fraction (a ramp of
another shape moves the face by a periodic function of the offset, up to 0.147 d for ``R``);
a steeper surface is sampled at every offset, where any profile antisymmetric about the
surface sums to the exact volume on average and the narrower ramp is the more accurate DDA
model (measured, ``docs/validation/exact_tmatrix.md``). ``delta`` moves the profile by the
surface's mean curvature times the profile's variance (``d^2 / 28`` for ``R``, ``d^2 / 12`` for
the plane fraction whatever ``n``), which cancels the volume a curved surface gains from a
symmetric profile.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "FACE_ALIGNMENT",
    "RAMP_HALF_WIDTH",
    "SUPPORT_HALF_WIDTH",
    "body_fraction",
    "box_cdf",
    "profile_weight",
    "ramp",
]

#: half-width of the C2 ramp :func:`ramp`, in units of d
RAMP_HALF_WIDTH = 0.5
#: normals with ``max_c |n_c|`` above this (within about 25 deg of a lattice axis) blend toward
#: the exact plane fraction, which they reach on a face parallel to a lattice plane
FACE_ALIGNMENT = 0.9
#: the fraction is 0 or 1 beyond this ``|s| / d`` (half the voxel's diagonal, sqrt(3) / 2, plus
#: room for ``delta``)
SUPPORT_HALF_WIDTH = 0.95
#: step of the central differences of the signed distance (normal, Laplacian), in units of d
DIFFERENCE_STEP = 1e-3
#: variances of the profiles' densities, in units of d^2: the C2 ramp's (a Beta(3, 3)
#: density on a unit interval) and the plane fraction's (that of ``n . u``, 1/12 for unit n)
RAMP_VARIANCE = 1.0 / 28.0
PLANE_VARIANCE = 1.0 / 12.0

#: widths (in units of d) below this are dropped from the box spline (the formula divides by
#: the product of the widths; dropping one moves the fraction by at most about width / 8)
SMALLEST_WIDTH = 1e-5

SignedDistance = Callable[[NDArray[np.float64]], NDArray[np.float64]]


def ramp(s: NDArray[np.float64], w: float = RAMP_HALF_WIDTH) -> NDArray[np.float64]:
    """Filling fraction for signed distance ``s`` in units of d (C2, exactly 0/1 outside |s|<w)."""
    t = np.clip((w - s) / (2.0 * w), 0.0, 1.0)
    return t * t * t * (t * (6.0 * t - 15.0) + 10.0)


def _truncated_sum(t: NDArray, widths: NDArray, power: int) -> NDArray:
    """``sum_e (-1)^|e| (t + sum w / 2 - e . w)_+^power`` over the corners ``e`` of the unit
    cube in ``k = widths.shape[1]`` dimensions (rows: points)."""
    k = widths.shape[1]
    start = t + 0.5 * widths.sum(axis=1)
    total = np.zeros_like(t)
    for corner in range(2**k):
        bits = np.array([(corner >> i) & 1 for i in range(k)], dtype=float)
        x = np.maximum(start - widths @ bits, 0.0)
        total += (-1.0) ** bits.sum() * x**power
    return total


def box_cdf(t: NDArray[np.float64], normals: NDArray[np.float64]) -> NDArray[np.float64]:
    """The fraction of a unit voxel on the side ``n . u < t`` of a plane: ``P(n . u < t)`` for
    ``u`` uniform in ``[-1/2, 1/2]^3``, the distribution of a sum of three uniform variables
    of widths ``|n_x|, |n_y|, |n_z|`` (a box spline; widths below :data:`SMALLEST_WIDTH` are
    dropped, the formula dividing by their product).

    Parameters
    ----------
    t : ndarray, shape (M,)
        Threshold, in units of the voxel side.
    normals : ndarray, shape (M, 3)
        Unit normals.

    Returns
    -------
    ndarray, shape (M,)
    """
    t = np.asarray(t, dtype=float)
    w = -np.sort(-np.abs(np.asarray(normals, dtype=float)), axis=1)
    flip = t > 0.0  # evaluate 1 - F(-t) there: fewer terms cancel
    tt = np.where(flip, -t, t)
    out = np.empty_like(tt)
    kept = (w > SMALLEST_WIDTH).sum(axis=1)
    for k in (1, 2, 3):
        rows = kept == k
        if np.any(rows):
            wk = w[rows, :k]
            denom = np.prod(wk, axis=1) * float(np.prod(np.arange(1, k + 1)))
            out[rows] = _truncated_sum(tt[rows], wk, k) / denom
    out = np.clip(out, 0.0, 1.0)
    return np.where(flip, 1.0 - out, out)


def profile_weight(normals: NDArray[np.float64]) -> NDArray[np.float64]:
    """``beta`` of the module docstring for unit normals ``(M, 3)``: 1 for a normal along a
    lattice axis, 0 beyond :data:`FACE_ALIGNMENT`, C1 in between."""
    a = np.abs(normals).max(axis=1)
    return np.clip((a - FACE_ALIGNMENT) / (1.0 - FACE_ALIGNMENT), 0.0, 1.0) ** 2


def _derivatives(sdf: SignedDistance, p: NDArray, h: float) -> tuple[NDArray, NDArray, NDArray]:
    """``s``, ``grad s`` and ``laplacian s`` at ``p`` by central differences of step ``h``."""
    s = sdf(p)
    grad = np.empty_like(p)
    lap = -6.0 * s
    for axis in range(3):
        step = np.zeros(3)
        step[axis] = h
        up, down = sdf(p + step), sdf(p - step)
        grad[:, axis] = (up - down) / (2.0 * h)
        lap = lap + up + down
    return s, grad, lap / (h * h)


def body_fraction(sdf: SignedDistance, p: NDArray[np.float64], d: float) -> NDArray[np.float64]:
    """Volume fraction inside the body of signed distance ``sdf`` of the voxels of side ``d``
    centred at ``p`` (module docstring).

    Parameters
    ----------
    sdf : callable
        Signed distance (um, negative inside) at points ``(M, 3)``; a first-order estimate is
        enough near the surface (it is divided by its gradient's norm).
    p : ndarray, shape (M, 3)
        Voxel centres, um, in a frame whose axes are the lattice's.
    d : float
        Voxel side, um.

    Returns
    -------
    ndarray, shape (M,)
    """
    s0 = sdf(p)
    out = (s0 < 0.0).astype(float)
    near = np.flatnonzero(np.abs(s0) < 1.5 * SUPPORT_HALF_WIDTH * d)
    if near.size == 0:
        return out
    s, grad, lap = _derivatives(sdf, p[near], DIFFERENCE_STEP * d)
    norm = np.linalg.norm(grad, axis=1)
    safe = np.where(norm > 0.0, norm, 1.0)
    unit = np.where((norm > 0.0)[:, None], grad / safe[:, None], 0.0)
    beta = profile_weight(unit)
    variance = (1.0 - beta) * RAMP_VARIANCE + beta * PLANE_VARIANCE
    # distance s / |grad s|; its Laplacian is lap / |grad s| to first order
    t = (s + 0.5 * lap * d * d * variance) / (safe * d)
    out[near] = (1.0 - beta) * ramp(t) + beta * box_cdf(-t, unit)
    return out
